"""The conversation loop: idle → listening → thinking → speaking → (follow-up) → idle.

Each 80 ms microphone frame goes through the wake detector and the VAD in a worker
thread. A wake word starts a turn: the utterance is recorded (pre-roll, silence end,
maximum length), transcribed, published on ``/sage/heard`` and sent to the brain's
``converse`` action; each sentence of its streamed feedback is spoken as it arrives
(:mod:`turn`). After the reply the robot listens ``follow_up_s`` more without a wake word.
A transcript the STT is unsure of (:meth:`TurnRunner.unclear`) is never sent to the brain:
the robot says it did not catch that and listens again (once; then it stays quiet).

While the visitor speaks, the utterance so far is transcribed early (on a pause) and
partially (for the face) by :mod:`live`.

The microphone's last second is kept (:class:`MicHistory`): on a wake word the utterance
starts where the wake phrase ended in it, not at the detection (which comes a frame or a few
later), so a visitor who runs on ("Hey Jarvis, where is the cafe") keeps the question's
first words; the frames since then are replayed into the VAD and the recorder. A wake
phrase Whisper still hears at the start of the transcript is stripped (:mod:`turn`); a
transcript that was only the wake phrase gets a follow-up window for the question.

A wake word while the robot thinks or speaks interrupts it (barge-in) — unless the robot
itself just said something that sounds like the wake word (its reference detector, see
:mod:`player`): its own voice is ignored. Text on ``/sage/say`` is spoken too.

While the navigator (``/nav/state``) is on its way and no conversation runs, the face's
phase is ``navigating`` instead of ``idle``; listening, thinking and speaking take precedence.
"""

from __future__ import annotations

import asyncio
import enum
from dataclasses import replace
from typing import Any

import numpy as np

from sage_robot.core.audio import SAMPLE_RATE_HZ
from sage_robot.core.bus import Bus
from sage_robot.core.clock import Clock
from sage_robot.core.config.areas import VoiceSettings
from sage_robot.core.log import StructLogger, get_logger
from sage_robot.core.msgs import Text
from sage_robot.core.msgs.nav import NavigateFeedback, NavState
from sage_robot.core.msgs.voice import Phase, TurnLatency, UiState
from sage_robot.core.topics import NAV_STATE, SAY, UI_STATE
from sage_robot.hardware.audio import Microphone
from sage_robot.voice.live import LiveTranscripts
from sage_robot.voice.partial import PartialTranscriber
from sage_robot.voice.player import Mouth
from sage_robot.voice.preroll import WAKE_ONLY, HeardFrame, MicHistory
from sage_robot.voice.stt import SpeechToText, Transcript
from sage_robot.voice.turn import TurnRunner, TurnTimes
from sage_robot.voice.vad import EndReason, SileroVad, Utterance, UtteranceRecorder
from sage_robot.voice.wake import Detection, WakeDetector

SELF_ECHO_WINDOW_S = 2.5  # a wake heard this soon after the robot "said" one is its own echo
# Navigator states in which the robot is on its way (the face shows "navigating" when idle).
MOVING_NAV_STATES = frozenset(
    {NavState.PLANNING, NavState.DRIVING, NavState.WAITING_FOR_PEOPLE, NavState.RECOVERING}
)


class State(str, enum.Enum):
    IDLE = "idle"
    LISTENING = "listening"  # recording an utterance (after a wake word or in follow-up)
    BUSY = "busy"  # a turn is transcribing, thinking or speaking


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
        self.wake, self.vad, self.stt = wake, vad, stt
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
        self.live = LiveTranscripts(clock, settings, stt, partial_stt, self._set_ui,
                                    lambda: self.state is State.LISTENING, self.log)  # fmt: skip
        self.turn = TurnRunner(bus, clock, settings, mouth, stt, self._set_ui, self.log)
        self._times: TurnTimes | None = None
        self._turn_task: asyncio.Task[None] | None = None
        self.history = MicHistory()  # the last second of frames: where the wake phrase ended
        self._follow_up = False
        self._say_task: asyncio.Task[int] | None = None
        self._asked_again = False  # the last turn ended in "did not catch that"
        self.not_caught = 0  # turns not acted on: the transcript was unclear
        self.navigating = False  # the navigator is on its way (from /nav/state)
        self.mouth.on_viseme = self._viseme

    @property
    def partial_stt(self) -> PartialTranscriber | None:
        """The second Whisper for partial transcripts (None: no partials); settable."""
        return self.live.partial_stt

    @partial_stt.setter
    def partial_stt(self, value: PartialTranscriber | None) -> None:
        self.live.partial_stt = value

    @property
    def latencies(self) -> list[TurnLatency]:
        return self.turn.latencies

    @property
    def early_transcripts(self) -> int:
        return self.live.early_transcripts

    @property
    def partials(self) -> int:
        return self.live.partials

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
            self.live.close()
            await self._stop_turn()

    def _analyse(self, frame: np.ndarray) -> tuple[list[Detection], float, dict[str, float]]:
        detections = self.wake.feed(frame)
        prob = self.vad.frame_probability(frame) if self.state is State.LISTENING else 0.0
        return detections, prob, dict(self.wake.last_scores)

    def _vad_probabilities(self, frames: list[np.ndarray]) -> list[float]:
        return [self.vad.frame_probability(f) for f in frames]

    async def process_frame(self, frame: np.ndarray) -> None:
        # When the frame was captured (a mic that lags still gets its echo right).
        frame_t = getattr(self.mic, "frame_time", None) or self.clock.now()
        detections, prob, scores = await self.clock.offload(self._analyse, frame)
        self.history.append(frame, frame_t, scores)
        detections = [d for d in detections if not self._own_voice(d, frame_t)]
        if detections and self._on_wake(detections[0]):
            # This frame and those before it since the wake phrase ended: the VAD and the
            # recorder start on them (the visitor may have run on into the question).
            await self._replay(*self.history.after_wake(detections[0].model))
            return
        self._listen(frame, frame_t, prob)

    async def _replay(self, lead_in: list[HeardFrame], frames: list[HeardFrame]) -> None:
        for f in lead_in:
            if not self.mouth.audible(f.time_s):
                self.recorder.lead_in(f.pcm)
        probs = await self.clock.offload(self._vad_probabilities, [f.pcm for f in frames])
        for f, prob in zip(frames, probs, strict=True):
            self._listen(f.pcm, f.time_s, prob)

    def _listen(self, frame: np.ndarray, frame_t: float, prob: float) -> None:
        """One frame (and its speech probability) into the utterance, while listening."""
        if self.state is not State.LISTENING or self.mouth.audible(frame_t):
            return  # not listening, or the robot's own voice: not the visitor's utterance
        utt = self.recorder.push(frame, prob)
        if utt is not None:
            self._on_utterance(utt)
        else:
            self.live.update(self.recorder)

    def _own_voice(self, det: Detection, frame_t: float) -> bool:
        t = self.mouth.last_self_wake
        if t is not None and abs(frame_t - t) <= SELF_ECHO_WINDOW_S:
            self.self_echoes_ignored += 1
            self.log.info("ignored own voice", model=det.model, score=round(det.score, 2))
            return True
        return False

    def _on_wake(self, det: Detection) -> bool:
        """A wake word: a new turn starts listening (True), or it is ignored (False)."""
        self.detections.append(det)
        if self.state is State.LISTENING and self.recorder.started and not self._follow_up:
            return False  # already recording what the visitor says after the wake word
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
        self._asked_again = False
        self.turns += 1
        self._times = TurnTimes(self.turns, self.clock.now())
        self._start_listening(self.settings.no_speech_timeout_s, follow_up=False)
        return True

    def _start_listening(self, timeout_s: float, follow_up: bool) -> None:
        self.state = State.LISTENING
        self._follow_up = follow_up
        self.recorder.reset()
        self.recorder.start_timeout_s = timeout_s
        self.vad.reset()
        self.live.start()
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
            self._times = TurnTimes(self.turns, self.clock.now() - len(utt.pcm) / SAMPLE_RATE_HZ)
        self._times.end_of_speech = self.clock.now()
        self.state = State.BUSY
        self._set_ui(phase=Phase.THINKING)
        early = self.live.take_early(utt)
        self._turn_task = asyncio.get_running_loop().create_task(
            self._turn(utt, self._times, early), name="voice.turn"
        )

    # ------------------------------------------------------------ one turn
    async def _turn(
        self, utt: Utterance, times: TurnTimes, early: asyncio.Future[Transcript] | None = None
    ) -> None:
        follow_up = False
        try:
            transcript = await self.turn.transcribe(utt, times, early)
            if self.turn.unclear(transcript):  # never act on text the STT is unsure of
                follow_up = await self._not_caught(times)
            elif transcript.rejected == WAKE_ONLY:  # "Hey Jarvis." alone: listen for the question
                follow_up = True
            elif not transcript.empty:  # nothing said: back to resting, not stuck "thinking"
                self._asked_again = False
                follow_up = await self.turn.converse(transcript.text, times)
        except asyncio.CancelledError:
            raise
        except Exception as exc:
            self.log.exception("voice turn failed", error=str(exc))
            self._set_ui(phase=Phase.ERROR, error_msg=f"voice: {exc}")
        finally:
            self.turn.finish(times)
        if follow_up and self.settings.follow_up_s > 0:
            self._start_listening(self.settings.follow_up_s, follow_up=True)
        else:
            self.state = State.IDLE
            self._set_resting()

    async def _not_caught(self, times: TurnTimes) -> bool:
        """Ask once to say it again (then listen, follow-up); quiet if that was just asked."""
        self.not_caught += 1
        if self._asked_again:
            return False
        self._asked_again = True
        await self.turn.not_caught(times)
        return True

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
                "not_caught": self.not_caught,
                "early_transcripts": self.live.early_transcripts, "partials": self.live.partials,
                "partials_skipped": self.live.partials_skipped,
                **self.mouth.stats()}  # fmt: skip
