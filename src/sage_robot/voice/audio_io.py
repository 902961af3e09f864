"""Audio plumbing: the pipeline's format, resampling, files, browser uploads, framing.

Internally everything is 16 kHz mono int16 (``SAMPLE_RATE_HZ``), cut into 80 ms frames
(``FRAME_SAMPLES``), the unit openWakeWord works in; both are defined in
:mod:`sage_robot.core.audio`. Resampling uses soxr (a proper band-limited resampler);
without it, scipy's polyphase filter.
"""

from __future__ import annotations

import io
import shutil
import subprocess
import wave
from math import gcd
from pathlib import Path
from typing import IO

import numpy as np

from sage_robot.core.audio import FRAME_SAMPLES, SAMPLE_RATE_HZ
from sage_robot.core.errors import SageError

INT16_FULL_SCALE = 32768.0
FFMPEG_TIMEOUT_S = 30.0  # longest a decode of an upload may take
MAX_UPLOAD_BYTES = 20 * 1024 * 1024  # refuse larger browser uploads (about 20 min of Opus)


class AudioError(SageError):
    """Audio that cannot be read, decoded or written; the message says why."""


def to_float(pcm: np.ndarray) -> np.ndarray:
    """int16 → float32 in [-1, 1); float input is returned as float32."""
    if pcm.dtype == np.int16:
        return pcm.astype(np.float32) / INT16_FULL_SCALE
    return pcm.astype(np.float32, copy=False)


def to_int16(pcm: np.ndarray) -> np.ndarray:
    """float in [-1, 1] (clipped) or int16 → int16."""
    if pcm.dtype == np.int16:
        return pcm
    scaled = np.clip(np.asarray(pcm, dtype=np.float32), -1.0, 1.0) * (INT16_FULL_SCALE - 1)
    return np.round(scaled).astype(np.int16)


def resample(pcm: np.ndarray, rate_in: int, rate_out: int = SAMPLE_RATE_HZ) -> np.ndarray:
    """Band-limited resampling of mono audio; keeps the dtype (int16 or float32)."""
    if rate_in <= 0 or rate_out <= 0:
        raise AudioError(f"sample rates must be positive, got {rate_in} → {rate_out}")
    if rate_in == rate_out or len(pcm) == 0:
        return pcm
    was_int = pcm.dtype == np.int16
    x = to_float(pcm)
    try:
        import soxr

        y = soxr.resample(x, rate_in, rate_out, quality="HQ")
    except ImportError:
        from scipy.signal import resample_poly

        g = gcd(rate_in, rate_out)
        y = resample_poly(x, rate_out // g, rate_in // g).astype(np.float32)
    return to_int16(y) if was_int else y.astype(np.float32)


def _mono(pcm: np.ndarray, channels: int, channel: int | None) -> np.ndarray:
    if channels == 1:
        return pcm
    frames = pcm.reshape(-1, channels)
    if channel is not None:
        if not 0 <= channel < channels:
            raise AudioError(f"channel {channel} does not exist; the audio has {channels}")
        return np.ascontiguousarray(frames[:, channel])
    mono: np.ndarray = frames.astype(np.int32).mean(axis=1).astype(np.int16)
    return mono


def read_wav(path: str | Path | IO[bytes], channel: int | None = None) -> tuple[np.ndarray, int]:
    """A 16-bit PCM WAV file (path or open binary file) → (int16 mono samples, sample rate)."""
    try:
        with wave.open(path if not isinstance(path, (str, Path)) else str(path), "rb") as w:
            if w.getsampwidth() != 2:
                raise AudioError(f"{path}: only 16-bit PCM WAV is read directly")
            rate, channels = w.getframerate(), w.getnchannels()
            data = np.frombuffer(w.readframes(w.getnframes()), dtype="<i2").astype(np.int16)
    except (wave.Error, EOFError) as exc:
        raise AudioError(f"{path}: not a readable WAV file ({exc})") from None
    return _mono(data, channels, channel), rate


def load_audio(path: str | Path, channel: int | None = None) -> np.ndarray:
    """Any audio file → 16 kHz mono int16.

    ``.raw`` / ``.pcm`` are headerless 16 kHz int16 (like Debian's pocketsphinx test data);
    16-bit WAV is read directly; anything else goes through ffmpeg.
    """
    p = Path(path)
    if not p.is_file():
        raise AudioError(f"{p}: no such audio file")
    suffix = p.suffix.lower()
    if suffix in (".raw", ".pcm"):
        data = p.read_bytes()
        if len(data) % 2:
            raise AudioError(f"{p}: raw audio must be 16-bit samples (odd byte count)")
        return np.frombuffer(data, dtype="<i2").astype(np.int16)
    if suffix == ".wav":
        try:
            pcm, rate = read_wav(p, channel)
            return resample(pcm, rate)
        except AudioError:
            pass  # e.g. float or 24-bit WAV: let ffmpeg handle it
    return decode_upload(p.read_bytes(), name=str(p))


def decode_upload(data: bytes, name: str = "upload") -> np.ndarray:
    """Browser upload (WebM/Opus, Ogg, MP3, WAV, ...) → 16 kHz mono int16, via ffmpeg."""
    if not data:
        raise AudioError(f"{name}: the audio is empty")
    if len(data) > MAX_UPLOAD_BYTES:
        raise AudioError(f"{name}: {len(data)} bytes is more than the {MAX_UPLOAD_BYTES} allowed")
    ffmpeg = shutil.which("ffmpeg")
    if ffmpeg is None:
        raise AudioError("ffmpeg is not installed (apt-get install ffmpeg)")
    cmd = [ffmpeg, "-hide_banner", "-loglevel", "error", "-i", "pipe:0", "-vn",
           "-ac", "1", "-ar", str(SAMPLE_RATE_HZ), "-f", "s16le", "pipe:1"]  # fmt: skip
    try:
        proc = subprocess.run(cmd, input=data, capture_output=True, timeout=FFMPEG_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        raise AudioError(f"{name}: ffmpeg took longer than {FFMPEG_TIMEOUT_S:g} s") from None
    if proc.returncode != 0:
        why = proc.stderr.decode("utf-8", "replace").strip().splitlines()
        raise AudioError(f"{name}: not audio ffmpeg can decode ({why[-1] if why else 'no detail'})")
    return np.frombuffer(proc.stdout, dtype="<i2").astype(np.int16)


def wav_bytes(pcm: np.ndarray, rate: int) -> bytes:
    """int16 (or float) mono samples → a WAV file in memory."""
    buf = io.BytesIO()
    with wave.open(buf, "wb") as w:
        w.setnchannels(1)
        w.setsampwidth(2)
        w.setframerate(int(rate))
        w.writeframes(to_int16(pcm).astype("<i2").tobytes())
    return buf.getvalue()


def write_wav(path: str | Path, pcm: np.ndarray, rate: int) -> Path:
    p = Path(path)
    try:
        p.write_bytes(wav_bytes(pcm, rate))
    except OSError as exc:
        raise AudioError(f"cannot write {p}: {exc.strerror or exc}") from None
    return p


class Framer:
    """Re-cuts a stream of arbitrary chunks into fixed frames (remainder kept for later)."""

    def __init__(self, frame_samples: int = FRAME_SAMPLES) -> None:
        self.frame_samples = frame_samples
        self._buf = np.zeros(0, dtype=np.int16)

    def push(self, chunk: np.ndarray) -> list[np.ndarray]:
        self._buf = np.concatenate([self._buf, to_int16(np.asarray(chunk))])
        n = len(self._buf) // self.frame_samples
        frames = [self._buf[i * self.frame_samples : (i + 1) * self.frame_samples] for i in range(n)]
        self._buf = self._buf[n * self.frame_samples :]
        return frames

    def reset(self) -> None:
        self._buf = np.zeros(0, dtype=np.int16)


def rms_dbfs(pcm: np.ndarray) -> float:
    """Loudness of a block in dB relative to full scale (−inf for digital silence)."""
    x = to_float(pcm)
    if len(x) == 0:
        return float("-inf")
    r = float(np.sqrt(np.mean(np.square(x, dtype=np.float64))))
    return 20.0 * np.log10(r) if r > 0 else float("-inf")
