"""The robot's mouth: streamed synthesis, playback in blocks, mouth signal, self-hearing.

:class:`Mouth` takes sentences as they arrive (an async iterator), synthesises each in a
worker thread while the previous one plays, and plays them in ``BLOCK_S`` blocks. For
each block it publishes an :class:`AudioChunk` (for the web pages) and the mouth opening
on ``/sage/ui_state``, and it feeds the block to a *reference* wake detector: what the
robot itself says. The pipeline uses that to ignore its own voice coming back through
the microphone, while a visitor's wake word still interrupts (barge-in).
"""

from __future__ import annotations

import asyncio
from collections import deque
from collections.abc import AsyncIterator, Callable
from typing import Any

import numpy as np

from sage_robot.core.audio import SAMPLE_RATE_HZ
from sage_robot.core.bus import Bus
from sage_robot.core.clock import Clock
from sage_robot.core.msgs.voice import AudioChunk
from sage_robot.core.topics import AUDIO_OUT
from sage_robot.hardware.audio import Speaker
from sage_robot.voice.audio_io import resample
from sage_robot.voice.tts import Speech, mouth_envelope
from sage_robot.voice.wake import WakeDetector

BLOCK_S = 0.1  # playback block (s): the unit of AudioChunk, mouth updates and barge-in
SYNTH_AHEAD = 3  # sentences synthesised ahead of the one playing
SELF_WAKE_THRESHOLD = 0.3  # the robot's own speech scoring this counts as saying a wake word
AUDIBLE_KEPT = 64  # playback intervals remembered for audible()
ECHO_TAIL_S = 0.35  # the room still rings (and buffers drain) this long after the audio ends
FIRST_CLAUSE_MIN_WORDS = 2  # the first spoken piece is at least this many words
REFERENCE_PRIME_S = 1.0  # silence fed to the reference detector before each utterance (s)


def first_clause(sentence: str) -> list[str]:
    """Cut a long first sentence at its first comma, colon or semicolon (after a few words)."""
    words = sentence.split()
    if len(words) < FIRST_CLAUSE_MIN_WORDS * 2:
        return [sentence]
    for i, w in enumerate(words[FIRST_CLAUSE_MIN_WORDS - 1 : -FIRST_CLAUSE_MIN_WORDS],
                          start=FIRST_CLAUSE_MIN_WORDS - 1):  # fmt: skip
        if w.endswith((",", ":", ";")):
            return [" ".join(words[: i + 1]), " ".join(words[i + 1 :])]
    return [sentence]


class Mouth:
    """Speaks streamed sentences; one utterance at a time (a lock serialises callers)."""

    def __init__(
        self,
        bus: Bus,
        clock: Clock,
        speech: Speech,
        speaker: Speaker,
        reference: WakeDetector | None = None,
        on_viseme: Callable[[float], None] | None = None,
    ) -> None:
        self.bus, self.clock, self.speech, self.speaker = bus, clock, speech, speaker
        self.reference = reference
        self.on_viseme = on_viseme
        self.lock = asyncio.Lock()
        self.speaking = False
        self.utterances = 0
        self.last_self_wake: float | None = None  # clock time the robot "said" a wake word
        self.last_audio_end: float | None = None
        self._play_end = 0.0  # clock time the audio handed to the speaker ends
        self._heard: deque[tuple[float, float]] = deque(maxlen=AUDIBLE_KEPT)  # (start, end)
        self.sentences_spoken = 0

    async def say(
        self,
        sentences: AsyncIterator[str],
        on_first_audio: Callable[[], None] | None = None,
    ) -> int:
        """Speak every sentence; returns how many were spoken. Cancel to stop (barge-in)."""
        async with self.lock:
            self.utterances += 1
            queue: asyncio.Queue[tuple[np.ndarray, int] | None] = asyncio.Queue(SYNTH_AHEAD)
            producer = asyncio.get_running_loop().create_task(self._synthesise(sentences, queue))
            spoken = 0
            first = True
            self.speaking = True
            try:
                if self.reference is not None:  # a detector scores best after some silence
                    silence = np.zeros(round(REFERENCE_PRIME_S * SAMPLE_RATE_HZ), dtype=np.int16)
                    await self.clock.offload(self.reference.feed, silence)
                while (item := await queue.get()) is not None:
                    pcm, rate = item
                    await self._play(pcm, rate, on_first_audio if first else None)
                    first = False
                    spoken += 1
                    self.sentences_spoken += 1
                await producer  # re-raise a synthesis error
            except asyncio.CancelledError:
                self.speaker.abort()
                self._cut_playback()
                raise
            finally:
                producer.cancel()
                await asyncio.gather(producer, return_exceptions=True)
                self.speaking = False
                self.last_audio_end = self.clock.now()
                self.speaker.end_utterance()
                self._publish(np.zeros(0, np.int16), self.speech.sample_rate, 0.0, final=True)
                if self.on_viseme:
                    self.on_viseme(0.0)
            return spoken

    async def say_text(self, text: str, on_first_audio: Callable[[], None] | None = None) -> int:
        async def one() -> AsyncIterator[str]:
            yield text

        return await self.say(one(), on_first_audio)

    async def _synthesise(
        self, sentences: AsyncIterator[str], queue: asyncio.Queue[tuple[np.ndarray, int] | None]
    ) -> None:
        first = True
        try:
            async for text in sentences:
                parts = self.speech.sentences(text)
                if first and parts:  # a short first piece: the reply starts sooner
                    parts = [*first_clause(parts[0]), *parts[1:]]
                first = False
                for sentence in parts:
                    pcm = await self.clock.offload(self.speech.engine.synthesize_sentence, sentence)
                    if len(pcm):
                        await queue.put((pcm, self.speech.sample_rate))
        finally:
            await queue.put(None)

    async def _play(self, pcm: np.ndarray, rate: int, on_first: Callable[[], None] | None) -> None:
        n = max(1, round(rate * BLOCK_S))
        mouth = mouth_envelope(pcm, rate)
        per_block = max(1, len(mouth) * n // max(1, len(pcm)))
        for k, i in enumerate(range(0, len(pcm), n)):
            block = pcm[i : i + n]
            opening = float(np.mean(mouth[k * per_block : (k + 1) * per_block])) if len(mouth) else 0.0
            self._publish(block, rate, opening)
            if self.on_viseme:
                self.on_viseme(round(opening, 2))
            start = max(self.clock.now(), self._play_end)
            self._play_end = start + len(block) / rate
            self._remember(start, self._play_end)
            if self.reference is not None:
                await self.clock.offload(self._hear_self, block, rate, start)
            if on_first is not None:
                on_first()
                on_first = None
            await self.speaker.play(block, rate)

    def _remember(self, start: float, end: float) -> None:
        if self._heard and start <= self._heard[-1][1] + 1e-6:
            self._heard[-1] = (self._heard[-1][0], end)
        else:
            self._heard.append((start, end))

    def _cut_playback(self) -> None:
        now = self.clock.now()
        self._play_end = now
        if self._heard and self._heard[-1][1] > now:
            self._heard[-1] = (self._heard[-1][0], now)

    def audible(self, t: float, tail_s: float = ECHO_TAIL_S) -> bool:
        """Was the robot's own voice in the room at clock time ``t`` (a mic frame's time)?"""
        return any(s <= t <= e + tail_s for s, e in reversed(self._heard))

    def _hear_self(self, block: np.ndarray, rate: int, start: float) -> None:
        assert self.reference is not None
        self.reference.feed(resample(block, rate, SAMPLE_RATE_HZ))
        if max(self.reference.last_scores.values(), default=0.0) >= SELF_WAKE_THRESHOLD:
            self.last_self_wake = start + len(block) / rate

    def _publish(self, block: np.ndarray, rate: int, viseme: float, final: bool = False) -> None:
        msg = AudioChunk(self.clock.now(), int(rate), block.astype("<i2").tobytes(),
                         round(viseme, 3), self.utterances, final)  # fmt: skip
        self.bus.publish(AUDIO_OUT, msg)

    def stats(self) -> dict[str, Any]:
        return {"utterances": self.utterances, "sentences_spoken": self.sentences_spoken}
