"""Transcripts started while the visitor is still speaking.

- **Early**: on a pause of ``EARLY_STT_S`` the final Whisper starts on the utterance so
  far. If nothing more is said, the pause ends the utterance and that transcript is the
  turn's (ready sooner); if the visitor goes on, it is dropped.
- **Partial**: every ``asr_partial_interval_s`` of audio (from ``PARTIAL_FIRST_S`` on) the
  utterance so far is re-transcribed by a second Whisper (``partial_stt``: a low-priority
  child process) and shown on the face as ``asr_partial``. A tick is skipped while the
  previous partial still runs or the visitor pauses (the final transcription may be about
  to start): partials never hold the final model or its CPU.

:class:`LiveTranscripts` does both for the pipeline (:mod:`sage_robot.voice.pipeline`),
one listening window at a time.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable

import numpy as np

from sage_robot.core.clock import Clock
from sage_robot.core.config.areas import VoiceSettings
from sage_robot.core.log import StructLogger
from sage_robot.voice.partial import PartialTranscriber
from sage_robot.voice.preroll import strip_wake_phrase
from sage_robot.voice.stt import SpeechToText, Transcript
from sage_robot.voice.turn import SetUi
from sage_robot.voice.vad import EndReason, Utterance, UtteranceRecorder

EARLY_STT_S = 0.3  # silence after which transcription starts, before the utterance is closed
PARTIAL_FIRST_S = 2.0  # utterance audio (pre-roll included) before the first partial: a short
# command gets none (its final comes as soon, and a partial would compete with it for the CPU)


class LiveTranscripts:
    """Early and partial transcripts of the utterance being recorded (see module doc)."""

    def __init__(
        self,
        clock: Clock,
        settings: VoiceSettings,
        stt: SpeechToText,
        partial_stt: PartialTranscriber | None,
        set_ui: SetUi,
        listening: Callable[[], bool],
        log: StructLogger,
    ) -> None:
        self.clock, self.settings, self.stt, self.partial_stt = clock, settings, stt, partial_stt
        self.set_ui, self.listening, self.log = set_ui, listening, log
        self.early_transcripts = 0  # turns whose transcript was started on the pause
        self.partials = 0  # partial transcripts shown
        self.partials_skipped = 0  # ticks skipped: the previous partial was still running
        self._listen_id = 0  # one per listening window: late partials of an old one are dropped
        self.partial_task: asyncio.Task[None] | None = None
        self._partial_at_s = 0.0  # utterance length at the last partial tick (s)
        self._early: tuple[float, asyncio.Future[Transcript]] | None = None  # (speech_s, STT)

    def start(self) -> None:
        """A new listening window: what was started in the last one is not shown or used."""
        self._early = None
        self._listen_id += 1
        self._partial_at_s = 0.0

    def update(self, rec: UtteranceRecorder) -> None:
        """After each frame the recorder took without closing the utterance."""
        self.transcribe_early(rec)
        self.transcribe_partial(rec)

    def take_early(self, utt: Utterance) -> asyncio.Future[Transcript] | None:
        """The early transcript when it is of exactly ``utt`` (closed by that silence)."""
        early = None
        if self._early is not None and self._early[0] == utt.speech_s and utt.reason is EndReason.SILENCE:
            early = self._early[1]
            self.early_transcripts += 1
        self._early = None
        return early

    def close(self) -> None:
        if self.partial_task is not None:
            self.partial_task.cancel()

    def transcribe_partial(self, rec: UtteranceRecorder) -> None:
        """Every ``asr_partial_interval_s`` of audio while the visitor speaks, transcribe the
        utterance so far for the face (skipped while the last one runs or on a pause)."""
        if self.partial_stt is None or not rec.started or rec.silent_s > 0:
            return
        due = max(PARTIAL_FIRST_S, self._partial_at_s + self.settings.asr_partial_interval_s)
        if rec.duration_s < due - 1e-9:
            return
        self._partial_at_s = rec.duration_s
        if self.partial_task is not None and not self.partial_task.done():
            self.partials_skipped += 1
            return
        self.partial_task = asyncio.get_running_loop().create_task(
            self._partial(self.partial_stt, rec.snapshot(), self._listen_id), name="voice.partial"
        )

    async def _partial(self, partial_stt: PartialTranscriber, pcm: np.ndarray, listen_id: int) -> None:
        try:
            transcript = await self.clock.offload(partial_stt.transcribe, pcm, True)
        except Exception as exc:  # a partial is only for show: the final still runs
            self.log.warning("partial transcript failed", error=str(exc))
            return
        text = strip_wake_phrase(transcript.text)
        if listen_id == self._listen_id and self.listening() and text:
            self.partials += 1
            self.set_ui(asr_partial=text)

    def transcribe_early(self, rec: UtteranceRecorder) -> None:
        """Start Whisper on a pause that will probably end the utterance: if nothing more
        is said, the transcript is ready sooner; if the visitor goes on, it is dropped."""
        if not rec.started:
            return
        if self._early is not None and rec.speech_s != self._early[0]:
            self._early = None  # the visitor spoke again
        if self._early is None and rec.silent_s >= EARLY_STT_S:
            pcm = rec.snapshot()
            fut = asyncio.ensure_future(self.clock.offload(self.stt.transcribe, pcm, True))
            fut.add_done_callback(lambda f: f.cancelled() or f.exception())  # dropped: no warning
            self._early = (rec.speech_s, fut)
