"""One conversation turn, once the visitor's utterance is recorded.

:class:`TurnRunner` transcribes the utterance (or takes the transcript started early, on
the visitor's pause) and publishes it on ``/sage/heard``; sends it to the brain's
``converse`` action and speaks each sentence of the streamed feedback as it arrives; and
at the end publishes the turn's latencies (:class:`TurnTimes`) on ``/sage/turn_latency``.
The order of the steps, errors, barge-in and what comes next (a follow-up window or
idle) are the pipeline's (:mod:`sage_robot.voice.pipeline`).
"""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from dataclasses import dataclass, replace
from typing import Any, Protocol

from sage_robot.core.bus import Bus
from sage_robot.core.clock import Clock
from sage_robot.core.config.areas import VoiceSettings
from sage_robot.core.log import StructLogger
from sage_robot.core.msgs import Text
from sage_robot.core.msgs.voice import Phase, TurnLatency
from sage_robot.core.topics import CONVERSE, HEARD, TURN_LATENCY
from sage_robot.voice.player import Mouth
from sage_robot.voice.preroll import WAKE_ONLY, strip_wake_phrase
from sage_robot.voice.stt import SpeechToText, Transcript
from sage_robot.voice.vad import Utterance

NO_BRAIN = "Sorry, my brain is not running right now."
BRAIN_FAILED = "Sorry, I could not come up with an answer."
NOT_CAUGHT = "Sorry, I did not catch that. Could you say it again?"
UI_TOKENS_MAX = 400  # characters of the reply shown on the face


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


class SetUi(Protocol):
    """Changes fields of the face's :class:`UiState` (published when something changed)."""

    def __call__(self, **changes: Any) -> None: ...


class TurnRunner:
    """The steps of a turn: transcribe, converse, finish (see module doc)."""

    def __init__(
        self,
        bus: Bus,
        clock: Clock,
        settings: VoiceSettings,
        mouth: Mouth,
        stt: SpeechToText,
        set_ui: SetUi,
        log: StructLogger,
    ) -> None:
        self.bus, self.clock, self.settings, self.mouth, self.stt = bus, clock, settings, mouth, stt
        self.set_ui, self.log = set_ui, log
        self.latencies: list[TurnLatency] = []

    async def transcribe(
        self, utt: Utterance, times: TurnTimes, early: asyncio.Future[Transcript] | None = None
    ) -> Transcript:
        """The utterance's transcript (``early`` when it was started on the pause); a
        non-empty one is shown on the face and published on ``/sage/heard``. A wake phrase
        at its start ("Hey Jarvis, where is ...": the visitor ran on) is left out; one that
        was all of it gives an empty transcript rejected as ``WAKE_ONLY``."""
        if early is not None:
            transcript = await early
        else:
            transcript = await self.clock.offload(self.stt.transcribe, utt.pcm, True)
        text = strip_wake_phrase(transcript.text)
        if text != transcript.text:
            transcript = replace(transcript, text=text, rejected="" if text else WAKE_ONLY)
        times.stt_done = self.clock.now()
        times.transcript = transcript.text
        self.log.info("heard", text=transcript.text, reason=utt.reason.value,
                      confidence=round(transcript.confidence, 2), rejected=transcript.rejected)  # fmt: skip
        if not transcript.empty and not self.unclear(transcript):
            self.set_ui(asr_final=transcript.text)
            self.bus.publish(HEARD, Text(transcript.text))
        return transcript

    def unclear(self, transcript: Transcript) -> bool:
        """Speech that must not be acted on: the STT kept nothing trustworthy, or what it
        kept is less sure than ``stt_min_confidence``."""
        if transcript.empty:
            return transcript.unclear
        return transcript.confidence < self.settings.stt_min_confidence

    async def not_caught(self, times: TurnTimes) -> None:
        """Say the robot did not catch that (instead of answering invented text)."""
        self.log.info("did not catch that", min_confidence=self.settings.stt_min_confidence)
        await self.mouth.say_text(NOT_CAUGHT, lambda: self._first_audio(times))

    async def converse(self, text: str, times: TurnTimes) -> bool:
        """Ask the brain and speak its streamed reply; True when a reply was spoken."""
        if not self.bus.actions.has(CONVERSE):
            self.log.warning("no brain: the converse action is not served")
            self.set_ui(error_msg="brain not running")
            await self.mouth.say_text(NO_BRAIN, lambda: self._first_audio(times))
            return False
        handle = await self.bus.actions.send_goal(CONVERSE, Text(text))
        tokens: list[str] = []

        async def sentences() -> AsyncIterator[str]:
            async for fb in handle.feedback():
                if times.first_token != times.first_token:  # NaN: first one
                    times.first_token = self.clock.now()
                tokens.append(fb.data)
                self.set_ui(llm_tokens=" ".join(tokens)[-UI_TOKENS_MAX:])
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
            self.set_ui(error_msg="the brain took too long")
            return False
        finally:
            if not handle.done:
                handle.request_cancel()  # barge-in or timeout: the brain stops by itself
        return bool(tokens)

    def _first_audio(self, times: TurnTimes) -> None:
        times.first_audio = self.clock.now()
        self.set_ui(phase=Phase.SPEAKING)

    def finish(self, times: TurnTimes) -> None:
        """The turn is over (answered, failed or cancelled): publish its latencies."""
        msg = times.message(self.clock.now())
        self.latencies.append(msg)
        self.bus.publish(TURN_LATENCY, msg)
        self.log.info("turn latency", turn=msg.turn, end_of_speech=round(msg.end_of_speech, 3),
                      stt_done=round(msg.stt_done, 3), first_sentence=round(msg.first_token, 3),
                      first_audio=round(msg.first_audio, 3),
                      reply_delay_s=round(msg.reply_delay_s, 3))  # fmt: skip
