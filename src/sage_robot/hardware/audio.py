"""Microphone and speaker through PortAudio (``sounddevice``).

Both sides implement the small interfaces the voice pipeline uses (the simulator's
audio in :mod:`sage_robot.sim.audio` implements the same ones):

- :class:`Microphone`: ``await read()`` → the next 80 ms frame, 16 kHz mono int16.
- :class:`Speaker`: ``await play(pcm, rate)`` plays a block and returns when it is
  queued about as far ahead as it lasts; ``abort()`` drops what is queued (barge-in);
  ``end_utterance()`` marks the end of one reply.

The device is chosen by (part of) its name; the XVF3800 gives several channels, of
which ``channel`` is used. Audio is resampled with soxr's streaming resampler.
"""

from __future__ import annotations

import asyncio
import contextlib
import queue
import time as _time
from typing import Any, Protocol

import numpy as np

from sage_robot.core.audio import FRAME_SAMPLES, SAMPLE_RATE_HZ
from sage_robot.core.errors import DeviceNotConnectedError

MIC_QUEUE_BLOCKS = 64  # about 5 s of 80 ms blocks before the oldest is dropped
READ_TIMEOUT_S = 2.0  # no audio for this long: the device is gone


class Microphone(Protocol):
    async def read(self) -> np.ndarray: ...

    def close(self) -> None: ...


class Speaker(Protocol):
    async def play(self, pcm: np.ndarray, rate: int) -> None: ...

    def abort(self) -> None: ...

    def end_utterance(self) -> None: ...

    def close(self) -> None: ...


def _sounddevice() -> Any:
    try:
        import sounddevice as sd
    except (ImportError, OSError) as exc:  # OSError: libportaudio2 missing
        raise DeviceNotConnectedError(
            f"audio devices need sounddevice and libportaudio2 ({exc})"
        ) from None
    return sd


def find_device(name: str, kind: str) -> int | None:
    """Index of the first ``kind`` ('input'/'output') device whose name contains ``name``."""
    sd = _sounddevice()
    if not name:
        return None
    channels_key = "max_input_channels" if kind == "input" else "max_output_channels"
    for i, dev in enumerate(sd.query_devices()):
        if name.lower() in str(dev["name"]).lower() and dev[channels_key] > 0:
            return i
    names = [d["name"] for d in sd.query_devices() if d[channels_key] > 0]
    raise DeviceNotConnectedError(f"no {kind} device named like {name!r}; found: {names}")


class SoundDeviceMicrophone:
    """A PortAudio input stream → 80 ms frames at 16 kHz."""

    def __init__(self, device: str = "", channel: int = 0) -> None:
        sd = _sounddevice()
        self._index = find_device(device, "input")
        try:
            info = sd.query_devices(self._index, "input")
        except Exception as exc:  # PortAudioError: no default input
            raise DeviceNotConnectedError(f"no microphone: {exc}") from None
        self.channel = channel
        channels = int(info["max_input_channels"])
        if channel >= channels:
            raise DeviceNotConnectedError(f"{info['name']} has {channels} channels, not {channel + 1}")
        self.rate = int(info["default_samplerate"])
        self._queue: queue.Queue[tuple[np.ndarray, float]] = queue.Queue(MIC_QUEUE_BLOCKS)
        self.frame_time: float | None = None  # wall time the last frame read was captured
        self._pending = np.zeros(0, dtype=np.int16)
        self.overflows = 0
        import soxr

        self._resampler = soxr.ResampleStream(self.rate, SAMPLE_RATE_HZ, 1, dtype="int16")
        try:
            self._stream = sd.InputStream(
                device=self._index, channels=channel + 1, samplerate=self.rate, dtype="int16",
                blocksize=round(self.rate * FRAME_SAMPLES / SAMPLE_RATE_HZ), callback=self._callback,
            )  # fmt: skip
            self._stream.start()
        except Exception as exc:
            raise DeviceNotConnectedError(f"cannot open microphone {info['name']}: {exc}") from None

    def _callback(self, indata: np.ndarray, frames: int, time: Any, status: Any) -> None:
        block = (np.ascontiguousarray(indata[:, self.channel]), _time.time())
        try:
            self._queue.put_nowait(block)
        except queue.Full:
            self.overflows += 1
            with contextlib.suppress(queue.Empty):
                self._queue.get_nowait()
            self._queue.put_nowait(block)

    async def read(self) -> np.ndarray:
        while len(self._pending) < FRAME_SAMPLES:
            try:
                block, self.frame_time = await asyncio.to_thread(self._queue.get, True, READ_TIMEOUT_S)
            except queue.Empty:
                raise DeviceNotConnectedError("the microphone stopped delivering audio") from None
            out = self._resampler.resample_chunk(block)
            self._pending = np.concatenate([self._pending, out.astype(np.int16)])
        frame, self._pending = self._pending[:FRAME_SAMPLES], self._pending[FRAME_SAMPLES:]
        return frame

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self._stream.stop()
            self._stream.close()


class SoundDeviceSpeaker:
    """A PortAudio output stream; reopened when the sample rate changes."""

    def __init__(self, device: str = "") -> None:
        self._sd = _sounddevice()
        self._index = find_device(device, "output")
        self._stream: Any = None
        self._rate = 0

    def _open(self, rate: int) -> None:
        self.close()
        try:
            self._stream = self._sd.OutputStream(device=self._index, channels=1, samplerate=rate,
                                                 dtype="int16")  # fmt: skip
            self._stream.start()
        except Exception as exc:
            raise DeviceNotConnectedError(f"cannot open the speaker: {exc}") from None
        self._rate = rate

    async def play(self, pcm: np.ndarray, rate: int) -> None:
        if self._stream is None or rate != self._rate:
            self._open(rate)
        await asyncio.to_thread(self._stream.write, np.ascontiguousarray(pcm, dtype=np.int16))

    def abort(self) -> None:
        if self._stream is not None:
            with contextlib.suppress(Exception):
                self._stream.abort()
                self._stream.start()

    def end_utterance(self) -> None:
        return None

    def close(self) -> None:
        if self._stream is not None:
            with contextlib.suppress(Exception):
                self._stream.close()
        self._stream = None
