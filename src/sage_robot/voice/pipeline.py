"""The conversation loop: idle → listening → thinking → speaking → (follow-up) → idle.

Each 80 ms microphone frame goes through the wake detector and the VAD in a worker
thread. A wake word starts a turn: the utterance is recorded (pre-roll, silence end,
maximum length), transcribed, published on ``/sage/heard`` and sent to the brain's
``converse`` action; each sentence of its streamed feedback is spoken as it arrives.
After the reply the robot listens ``follow_up_s`` more without a wake word.

While the visitor speaks, every ``asr_partial_interval_s`` of audio (from
``PARTIAL_FIRST_S`` on) the utterance so far is re-transcribed by a second Whisper
(``partial_stt``: a low-priority child process) and shown as ``asr_partial``; a tick is
skipped while the previous partial still runs or the visitor pauses (the final
transcription may be about to start); partials never hold the final model or its CPU.

A wake word while the robot thinks or speaks interrupts it (barge-in) — unless the robot
itself just said something that sounds like the wake word (its reference detector, see
:mod:`player`): its own voice is ignored. Text on ``/sage/say`` is spoken too.

While the navigator (``/nav/state``) is on its way and no conversation runs, the face's
phase is ``navigating`` instead of ``idle``; listening, thinking and speaking take precedence.
"""

from __future__ import annotations

import asyncio
import enum
from collections.abc import AsyncIterator
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from sage_robot.core.bus import Bus
from sage_robot.core.clock import Clock
from sage_robot.core.config.areas import VoiceSettings
from sage_robot.core.log import StructLogger, get_logger
from sage_robot.core.msgs import Text
from sage_robot.core.msgs.nav import NavigateFeedback, NavState
from sage_robot.core.msgs.voice import Phase, TurnLatency, UiState
from sage_robot.core.topics import CONVERSE, HEARD, NAV_STATE, SAY, TURN_LATENCY, UI_STATE
from sage_robot.hardware.audio import Microphone
from sage_robot.voice.partial import PartialTranscriber
from sage_robot.voice.player import Mouth
from sage_robot.voice.stt import SpeechToText, Transcript
from sage_robot.voice.vad import EndReason, SileroVad, Utterance, UtteranceRecorder
from sage_robot.voice.wake import Detection, WakeDetector

SELF_ECHO_WINDOW_S = 2.5  # a wake heard this soon after the robot "said" one is its own echo
EARLY_STT_S = 0.3  # silence after which transcription starts, before the utterance is closed
PARTIAL_FIRST_S = 2.0  # utterance audio (pre-roll included) before the first partial: a short
# command gets none (its final comes as soon, and a partial would compete with it for the CPU)
WAKE_TAIL_S = 0.24  # audio right after a detection is the end of the wake phrase: skipped
NO_BRAIN = "Sorry, my brain is not running right now."
BRAIN_FAILED = "Sorry, I could not come up with an answer."
UI_TOKENS_MAX = 400  # characters of the reply shown on the face
# Navigator states in which the robot is on its way (the face shows "navigating" when idle).
MOVING_NAV_STATES = frozenset(
    {NavState.PLANNING, NavState.DRIVING, NavState.WAITING_FOR_PEOPLE, NavState.RECOVERING}
)


class State(str, enum.Enum):
    IDLE = "idle"
    LISTENING = "listening"  # recording an utterance (after a wake word or in follow-up)
    BUSY = "busy"  # a turn is transcribing, thinking or speaking


@dataclass
class TurnTimes:
    turn: int
    wake: float
    end_of_speech: float = float("nan")
    stt_done: float = float("nan")
    first_token: float = float("nan")
    first_audio: float = float("nan")
    transcript: str = ""

    def message(self, stamp: float) -> TurnLatency:
        def rel(t: float) -> float:
            return t - self.wake

        return TurnLatency(stamp, self.turn, 0.0, rel(self.end_of_speech), rel(self.stt_done),
                           rel(self.first_token), rel(self.first_audio), self.transcript)  # fmt: skip


class VoicePipeline:
    """Runs the loop on one microphone and one mouth (see module doc)."""

    def __init__(
        self,
        bus: Bus,
        clock: Clock,
        settings: VoiceSettings,
        mic: Microphone,
        mouth: Mouth,
        wake: WakeDetector,
        vad: SileroVad,
        stt: SpeechToText,
        log: StructLogger | None = None,
        partial_stt: PartialTranscriber | None = None,
    ) -> None:
        self.bus, self.clock, self.settings, self.mic, self.mouth = bus, clock, settings, mic, mouth
        self.wake, self.vad, self.stt, self.partial_stt = wake, vad, stt, partial_stt
        self.log = log or get_logger("voice")
        self.recorder = UtteranceRecorder(settings.vad_threshold, settings.vad_silence_s,
                                          settings.vad_preroll_s, settings.max_utterance_s,
                                          settings.no_speech_timeout_s)  # fmt: skip
        self.state = State.IDLE
        self.ui = UiState()
        self.turns = 0
        self.detections: list[Detection] = []
        self.barge_ins = 0
        self.self_echoes_ignored = 0
        self.early_transcripts = 0  # turns whose transcript was started on the pause
        self.partials = 0  # partial transcripts shown
        self.partials_skipped = 0  # ticks skipped: the previous partial was still running
        self._listen_id = 0  # one per listening window: late partials of an old one are dropped
        self._partial_task: asyncio.Task[None] | None = None
        self._partial_at_s = 0.0  # utterance length at the last partial tick (s)
        self.latencies: list[TurnLatency] = []
        self._times: TurnTimes | None = None
        self._turn_task: asyncio.Task[None] | None = None
        self._skip_s = 0.0
        self._follow_up = False
        self._say_task: asyncio.Task[int] | None = None
        self._early: tuple[float, asyncio.Future[Transcript]] | None = None  # (speech_s, STT)
        self.navigating = False  # the navigator is on its way (from /nav/state)
        self.mouth.on_viseme = self._viseme

    # ------------------------------------------------------------ ui state
    def _set_ui(self, **changes: Any) -> None:
        new = replace(self.ui, **changes)
        if new != self.ui:
            self.ui = new
            self.bus.publish(UI_STATE, new)

    @property
    def resting_phase(self) -> Phase:
        """What the face shows when no conversation runs."""
        return Phase.NAVIGATING if self.navigating else Phase.IDLE

    def _set_resting(self) -> None:
        self._set_ui(phase=self.resting_phase)

    def _on_nav_state(self, msg: NavigateFeedback) -> None:
        self.navigating = msg.state in MOVING_NAV_STATES
        if self.state is State.IDLE and not self.mouth.speaking:
            self._set_resting()

    def _viseme(self, opening: float) -> None:
        if self.mouth.speaking:
            self._set_ui(phase=Phase.SPEAKING, tts_viseme=opening)
        else:
            self._set_ui(tts_viseme=0.0)

    # ------------------------------------------------------------ main loop
    async def run(self) -> None:
        """Read the microphone forever (cancel to stop)."""
        self.bus.subscribe(SAY, Text, self._on_say)
        self.bus.subscribe(NAV_STATE, NavigateFeedback, self._on_nav_state)
        self.bus.publish(UI_STATE, self.ui)  # the face's first state
        try:
            while True:
                frame = await self.mic.read()
                await self.process_frame(frame)
        finally:
            if self._partial_task is not None:
                self._partial_task.cancel()
            await self._stop_turn()

    def _analyse(self, frame: np.ndarray) -> tuple[list[Detection], float]:
        detections = self.wake.feed(frame)
        prob = self.vad.frame_probability(frame) if self.state is State.LISTENING else 0.0
        return detections, prob

    async def process_frame(self, frame: np.ndarray) -> None:
        # When the frame was captured (a mic that lags still gets its echo right).
        frame_t = getattr(self.mic, "frame_time", None) or self.clock.now()
        detections, prob = await self.clock.offload(self._analyse, frame)
        detections = [d for d in detections if not self._own_voice(d, frame_t)]
        if detections:
            self._on_wake(detections[0])
        if self.state is State.LISTENING and self.mouth.audible(frame_t):
            return  # the robot's own voice: not the visitor's utterance
        if self.state is State.LISTENING:
            if self._skip_s > 0:
                self._skip_s -= len(frame) / 16000
                return
            utt = self.recorder.push(frame, prob)
            if utt is not None:
                self._on_utterance(utt)
            else:
                self._transcribe_early()
                self._transcribe_partial()

    def _transcribe_partial(self) -> None:
        """Every ``asr_partial_interval_s`` of audio while the visitor speaks, transcribe the
        utterance so far for the face (skipped while the last one runs or on a pause)."""
        rec = self.recorder
        if self.partial_stt is None or not rec.started or rec.silent_s > 0:
            return
        due = max(PARTIAL_FIRST_S, self._partial_at_s + self.settings.asr_partial_interval_s)
        if rec.duration_s < due - 1e-9:
            return
        self._partial_at_s = rec.duration_s
        if self._partial_task is not None and not self._partial_task.done():
            self.partials_skipped += 1
            return
        self._partial_task = asyncio.get_running_loop().create_task(
            self._partial(rec.snapshot(), self._listen_id), name="voice.partial"
        )

    async def _partial(self, pcm: np.ndarray, listen_id: int) -> None:
        assert self.partial_stt is not None
        try:
            transcript = await self.clock.offload(self.partial_stt.transcribe, pcm, True)
        except Exception as exc:  # a partial is only for show: the final still runs
            self.log.warning("partial transcript failed", error=str(exc))
            return
        if listen_id == self._listen_id and self.state is State.LISTENING and transcript.text:
            self.partials += 1
            self._set_ui(asr_partial=transcript.text)

    def _transcribe_early(self) -> None:
        """Start Whisper on a pause that will probably end the utterance: if nothing more
        is said, the transcript is ready sooner; if the visitor goes on, it is dropped."""
        rec = self.recorder
        if not rec.started:
            return
        if self._early is not None and rec.speech_s != self._early[0]:
            self._early = None  # the visitor spoke again
        if self._early is None and rec.silent_s >= EARLY_STT_S:
            pcm = rec.snapshot()
            fut = asyncio.ensure_future(self.clock.offload(self.stt.transcribe, pcm, True))
            fut.add_done_callback(lambda f: f.cancelled() or f.exception())  # dropped: no warning
            self._early = (rec.speech_s, fut)

    def _own_voice(self, det: Detection, frame_t: float) -> bool:
        t = self.mouth.last_self_wake
        if t is not None and abs(frame_t - t) <= SELF_ECHO_WINDOW_S:
            self.self_echoes_ignored += 1
            self.log.info("ignored own voice", model=det.model, score=round(det.score, 2))
            return True
        return False

    def _on_wake(self, det: Detection) -> None:
        self.detections.append(det)
        if self.state is State.LISTENING and self.recorder.started and not self._follow_up:
            return  # already recording what the visitor says after the wake word
        busy = self.state is State.BUSY or self.mouth.speaking
        if busy:
            self.barge_ins += 1
            self.log.info("barge-in", model=det.model, score=round(det.score, 2))
            task = self._turn_task
            self._turn_task = None
            for t in (task, self._say_task):
                if t is not None:
                    t.cancel()
        self.log.info("wake word", model=det.model, score=round(det.score, 2))
        self.turns += 1
        self._times = TurnTimes(self.turns, self.clock.now())
        self._start_listening(self.settings.no_speech_timeout_s, follow_up=False)

    def _start_listening(self, timeout_s: float, follow_up: bool) -> None:
        self.state = State.LISTENING
        self._follow_up = follow_up
        self.recorder.reset()
        self.recorder.start_timeout_s = timeout_s
        self.vad.reset()
        self._early = None
        self._listen_id += 1
        self._partial_at_s = 0.0
        self._skip_s = 0.0 if follow_up else WAKE_TAIL_S
        self._set_ui(phase=Phase.LISTENING, asr_partial="", asr_final="", llm_tokens="",
                     error_msg="", tts_viseme=0.0)  # fmt: skip

    def _on_utterance(self, utt: Utterance) -> None:
        if utt.reason is EndReason.NO_SPEECH:
            self.log.info("nobody spoke" if not self._follow_up else "follow-up window closed")
            self.state = State.IDLE
            self._set_resting()
            return
        if self._times is None or self._follow_up:
            self.turns += 1
            self._times = TurnTimes(self.turns, self.clock.now() - len(utt.pcm) / 16000)
        self._times.end_of_speech = self.clock.now()
        self.state = State.BUSY
        self._set_ui(phase=Phase.THINKING)
        early = None
        if self._early is not None and self._early[0] == utt.speech_s and utt.reason is EndReason.SILENCE:
            early = self._early[1]
            self.early_transcripts += 1
        self._early = None
        self._turn_task = asyncio.get_running_loop().create_task(
            self._turn(utt, self._times, early), name="voice.turn"
        )

    # ------------------------------------------------------------ one turn
    async def _turn(
        self, utt: Utterance, times: TurnTimes, early: asyncio.Future[Transcript] | None = None
    ) -> None:
        follow_up = False
        try:
            if early is not None:
                transcript = await early
            else:
                transcript = await self.clock.offload(self.stt.transcribe, utt.pcm, True)
            times.stt_done = self.clock.now()
            times.transcript = transcript.text
            self.log.info("heard", text=transcript.text, reason=utt.reason.value,
                          confidence=round(transcript.confidence, 2))  # fmt: skip
            if transcript.empty:
                return
            self._set_ui(asr_final=transcript.text)
            self.bus.publish(HEARD, Text(transcript.text))
            follow_up = await self._converse(transcript.text, times)
        except asyncio.CancelledError:
            raise
        except Exception as exc:
            self.log.exception("voice turn failed", error=str(exc))
            self._set_ui(phase=Phase.ERROR, error_msg=f"voice: {exc}")
        finally:
            self._finish_turn(times)
        if follow_up and self.settings.follow_up_s > 0:
            self._start_listening(self.settings.follow_up_s, follow_up=True)
        else:
            self.state = State.IDLE
            self._set_resting()

    async def _converse(self, text: str, times: TurnTimes) -> bool:
        """Ask the brain and speak its streamed reply; True when a reply was spoken."""
        if not self.bus.actions.has(CONVERSE):
            self.log.warning("no brain: the converse action is not served")
            self._set_ui(error_msg="brain not running")
            await self.mouth.say_text(NO_BRAIN, lambda: self._first_audio(times))
            return False
        handle = await self.bus.actions.send_goal(CONVERSE, Text(text))
        tokens: list[str] = []

        async def sentences() -> AsyncIterator[str]:
            async for fb in handle.feedback():
                if times.first_token != times.first_token:  # NaN: first one
                    times.first_token = self.clock.now()
                tokens.append(fb.data)
                self._set_ui(llm_tokens=" ".join(tokens)[-UI_TOKENS_MAX:])
                yield fb.data
            result = await handle.result()
            if not tokens and result.ok and isinstance(result.value, Text) and result.value.data:
                times.first_token = self.clock.now()
                tokens.append(result.value.data)
                yield result.value.data
            elif not result.ok:
                self.log.warning("brain failed", status=result.status.value, reason=result.message)
                if not tokens:
                    yield BRAIN_FAILED

        try:
            await self.clock.wait_for(
                self.mouth.say(sentences(), lambda: self._first_audio(times)),
                self.settings.brain_timeout_s,
            )
        except asyncio.TimeoutError:
            self.log.warning("brain timed out", timeout_s=self.settings.brain_timeout_s)
            self._set_ui(error_msg="the brain took too long")
            return False
        finally:
            if not handle.done:
                handle.request_cancel()  # barge-in or timeout: the brain stops by itself
        return bool(tokens)

    def _first_audio(self, times: TurnTimes) -> None:
        times.first_audio = self.clock.now()
        self._set_ui(phase=Phase.SPEAKING)

    def _finish_turn(self, times: TurnTimes) -> None:
        msg = times.message(self.clock.now())
        self.latencies.append(msg)
        self.bus.publish(TURN_LATENCY, msg)
        self.log.info("turn latency", turn=msg.turn, end_of_speech=round(msg.end_of_speech, 3),
                      stt_done=round(msg.stt_done, 3), first_sentence=round(msg.first_token, 3),
                      first_audio=round(msg.first_audio, 3),
                      reply_delay_s=round(msg.reply_delay_s, 3))  # fmt: skip

    async def _stop_turn(self) -> None:
        task, self._turn_task = self._turn_task, None
        if task is not None:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)

    # ------------------------------------------------------------ /sage/say
    async def _on_say(self, msg: Text) -> None:
        if not msg.data.strip():
            return
        self.log.info("say", text=msg.data)
        self._say_task = asyncio.get_running_loop().create_task(self.mouth.say_text(msg.data))
        await asyncio.gather(self._say_task, return_exceptions=True)  # barge-in cancels it
        self._say_task = None
        if self.state is State.IDLE and not self.mouth.speaking:
            self._set_resting()

    async def wait_idle(self, poll_s: float = 0.05) -> None:
        """Until no turn runs and nothing is being said (tests, benchmarks)."""
        while self.state is not State.IDLE or self.mouth.speaking or self._turn_task is not None:
            if self._turn_task is not None and self._turn_task.done():
                self._turn_task = None
                continue
            await self.clock.sleep(poll_s)

    def stats(self) -> dict[str, Any]:
        return {"state": self.state.value, "turns": self.turns, "barge_ins": self.barge_ins,
                "wakes": len(self.detections), "self_echoes_ignored": self.self_echoes_ignored,
                "early_transcripts": self.early_transcripts, "partials": self.partials,
                "partials_skipped": self.partials_skipped,
                **self.mouth.stats()}  # fmt: skip
