"""Simulated microphone and speaker (same interfaces as :mod:`sage_robot.hardware.audio`).

- :class:`SimMicrophone` delivers 80 ms frames of 16 kHz int16 paced by the node's clock:
  a quiet noise floor, plus whatever a simulated visitor says (:meth:`inject`: audio
  rendered from text by the voice node, or a WAV file's samples), plus the echo of the
  robot's own speaker (the seed's speakerphone had poor echo cancellation).
- :class:`SimSpeaker` "plays" blocks in clock time through a small sound-card buffer
  (``SPEAKER_BUFFER_S`` queued ahead), feeds them back to the microphone as echo, keeps
  each utterance and writes it as a WAV file when ``out_dir`` is set.
"""

from __future__ import annotations

import asyncio
import io
import wave
from collections import deque
from math import gcd
from pathlib import Path

import numpy as np

from sage_robot.core.audio import FRAME_S, FRAME_SAMPLES, SAMPLE_RATE_HZ
from sage_robot.core.clock import Clock

SPEAKER_BUFFER_S = 0.3  # audio queued ahead in the (simulated) sound card (s)
MAX_LAG_S = 0.5  # a reader further behind the clock than this skips silent frames
NOISE_FLOOR_RMS = 30.0  # int16 units: about -60 dBFS of room noise
ECHO_GAIN = 0.5  # fraction of the speaker's signal that reaches the microphone
MAX_UTTERANCES_KEPT = 50  # the speaker's memory of past utterances (tests, web)


def _resample_to_mic(pcm: np.ndarray, rate: int) -> np.ndarray:
    if rate == SAMPLE_RATE_HZ:
        return pcm.astype(np.float32)
    from scipy.signal import resample_poly

    g = gcd(rate, SAMPLE_RATE_HZ)
    out: np.ndarray = resample_poly(pcm.astype(np.float32), SAMPLE_RATE_HZ // g, rate // g).astype(np.float32)
    return out


class SimMicrophone:
    """A microphone in the simulated room."""

    def __init__(
        self, clock: Clock, seed: int = 7, noise_rms: float = NOISE_FLOOR_RMS, paced: bool = True
    ) -> None:
        self.clock, self.noise_rms, self.paced = clock, noise_rms, paced
        self._rng = np.random.default_rng(seed)
        self._voice: deque[np.ndarray] = deque()  # visitor audio still to come
        self._echo = np.zeros(0, dtype=np.float32)  # starts at clock time _echo_t
        self._echo_t: float | None = None
        self._t0: float | None = None
        self.frames = 0
        self.closed = False
        self.waiting = False  # True while read() waits for its frame's time
        # Set while the clock may step on: read() waits for its frame's time, or the mic is closed.
        self._clock_free = asyncio.Event()
        self.frame_time: float | None = None  # clock time the last frame read ends
        self.skipped = 0  # silent frames skipped because the reader fell behind

    async def lockstep(self, dt: float = 0.0) -> None:
        """A SimClock ``on_step`` hook: hold the clock until the reader asked for its next
        frame, so simulated time never runs ahead of a slow consumer (tests, benchmarks).
        Before the first read there is no reader to wait for."""
        if self._t0 is not None:
            await self._clock_free.wait()

    def _set_waiting(self, waiting: bool) -> None:
        self.waiting = waiting
        if waiting or self.closed:
            self._clock_free.set()
        else:
            self._clock_free.clear()

    def inject(self, pcm16k: np.ndarray) -> float:
        """Queue a visitor's audio (16 kHz int16); returns its length in seconds."""
        pcm = np.asarray(pcm16k, dtype=np.int16)
        self._voice.append(pcm)
        return len(pcm) / SAMPLE_RATE_HZ

    @property
    def pending_s(self) -> float:
        """Seconds of visitor audio not yet heard."""
        return sum(len(v) for v in self._voice) / SAMPLE_RATE_HZ

    def add_echo(self, pcm: np.ndarray, rate: int, at: float, gain: float = ECHO_GAIN) -> None:
        """The speaker's sound reaches the mic from clock time ``at`` on."""
        base = self._echo_t if self._echo_t is not None else self.clock.now()
        x = _resample_to_mic(pcm, rate) * gain
        offset = round((at - base) * SAMPLE_RATE_HZ)
        if offset < 0:
            x, offset = x[-offset:], 0
        end = offset + len(x)
        if end > len(self._echo):
            self._echo = np.concatenate([self._echo, np.zeros(end - len(self._echo), np.float32)])
        self._echo[offset:end] += x

    def clear_echo(self) -> None:
        """The speaker stopped: the sound it had not played yet never arrives."""
        now = self.clock.now()
        if self._echo_t is not None:
            keep = max(0, round((now - self._echo_t) * SAMPLE_RATE_HZ))
            self._echo = self._echo[:keep]

    def _take_voice(self, n: int) -> np.ndarray:
        out = np.zeros(n, dtype=np.float32)
        filled = 0
        while filled < n and self._voice:
            head = self._voice[0]
            k = min(n - filled, len(head))
            out[filled : filled + k] = head[:k]
            filled += k
            if k == len(head):
                self._voice.popleft()
            else:
                self._voice[0] = head[k:]
        return out

    async def read(self) -> np.ndarray:
        """The next 80 ms frame, at its time on the clock."""
        if self._t0 is None:
            self._t0 = self._echo_t = self.clock.phase(FRAME_S)
        self._skip_silence_when_behind()
        self.frames += 1
        if self.paced:
            self._set_waiting(True)
            try:
                await self.clock.sleep_until(self._t0 + self.frames * FRAME_S)
            finally:
                self._set_waiting(False)
        x = self._rng.normal(0.0, self.noise_rms, FRAME_SAMPLES).astype(np.float32)
        x += self._take_voice(FRAME_SAMPLES)
        k = min(FRAME_SAMPLES, len(self._echo))
        x[:k] += self._echo[:k]
        self._echo = self._echo[k:]
        self._echo_t = (self._echo_t or 0.0) + FRAME_S
        self.frame_time = self._t0 + self.frames * FRAME_S
        return np.clip(np.round(x), -32768, 32767).astype(np.int16)

    def _skip_silence_when_behind(self) -> None:
        """A reader slower than simulated time (``sage sim --fast``) skips ahead over frames
        with nothing in them but the noise floor, as a real mic's full buffer drops audio;
        a visitor's words and the robot's echo are never skipped."""
        assert self._t0 is not None  # read() sets both before it comes here
        assert self._echo_t is not None
        behind = self.clock.now() - (self._t0 + self.frames * FRAME_S)
        if behind > MAX_LAG_S and not self._voice and len(self._echo) == 0:
            skip = int(behind / FRAME_S) - 1  # the next frame stays due now, not later
            self.frames += skip
            self._echo_t += skip * FRAME_S
            self.skipped += skip

    def close(self) -> None:
        self.closed = True
        self._clock_free.set()


class SimSpeaker:
    """A speaker in the simulated room: clock-paced, echoing into ``mic``."""

    def __init__(
        self,
        clock: Clock,
        mic: SimMicrophone | None = None,
        out_dir: str | Path | None = None,
        echo_gain: float = ECHO_GAIN,
    ) -> None:
        self.clock, self.mic, self.echo_gain = clock, mic, echo_gain
        self.out_dir = Path(out_dir) if out_dir else None
        self._current: list[np.ndarray] = []
        self._rate = 0
        self.utterances: deque[tuple[np.ndarray, int]] = deque(maxlen=MAX_UTTERANCES_KEPT)
        self.files: list[Path] = []
        self.aborted = 0
        self.seconds_played = 0.0
        self._play_until = 0.0  # clock time the queued audio ends

    async def play(self, pcm: np.ndarray, rate: int) -> None:
        if self._current and rate != self._rate:
            self.end_utterance()
        self._rate = rate
        self._current.append(np.asarray(pcm, dtype=np.int16))
        start = max(self.clock.now(), self._play_until)
        duration = len(pcm) / rate
        if self.mic is not None and self.echo_gain > 0:
            self.mic.add_echo(pcm, rate, start, self.echo_gain)
        self._play_until = start + duration
        self.seconds_played += duration
        await self.clock.sleep_until(self._play_until - SPEAKER_BUFFER_S)

    def abort(self) -> None:
        self.aborted += 1
        self._play_until = self.clock.now()
        if self.mic is not None:
            self.mic.clear_echo()
        self.end_utterance()

    def end_utterance(self) -> None:
        if not self._current:
            return
        pcm = np.concatenate(self._current)
        self._current = []
        self.utterances.append((pcm, self._rate))
        if self.out_dir is not None:
            self.out_dir.mkdir(parents=True, exist_ok=True)
            path = self.out_dir / f"robot_{len(self.files) + 1:04d}.wav"
            path.write_bytes(_wav(pcm, self._rate))
            self.files.append(path)

    def close(self) -> None:
        self.end_utterance()


def _wav(pcm: np.ndarray, rate: int) -> bytes:
    buf = io.BytesIO()
    with wave.open(buf, "wb") as w:
        w.setnchannels(1)
        w.setsampwidth(2)
        w.setframerate(rate)
        w.writeframes(pcm.astype("<i2").tobytes())
    return buf.getvalue()
