"""Wake words: an engine scores each 80 ms frame; a detector applies threshold and refractory.

The engine is behind :class:`WakeEngine` so a deployment can swap it: the bundled one,
:class:`OpenWakeWordEngine`, runs openWakeWord's ONNX models (pre-trained models are
CC BY-NC-SA; they come with the optional ``voice-gpl`` extra). A name like ``hey_jarvis``
is a bundled model; a path ending in ``.onnx`` is a custom model (e.g. the owners' "hey sage"),
judged by openWakeWord's conventions (0.5, one frame) unless the profile says otherwise
(``sage voice wake calibrate`` picks its threshold and patience from recordings).

Scores do not depend on how the audio is chunked: :class:`WakeDetector` re-cuts any
stream into exact 80 ms frames before the engine sees it, and the engine's feature
buffers start from a fixed (seeded) state.

More paths can hear the same wake word; a model is detected when any path passes:
- ``heads``: a small classifier per model on the engine's speech embeddings
  (:mod:`sage_robot.voice.wake_head`), trained for heavy noise. It counts only while the
  model's own smoothed score is at least ``head_gate``: the head alone never wakes the
  robot on audio the model finds nothing like its wake word in.
- ``denoised``: the same frames through a streaming stationary-noise suppressor
  (:mod:`sage_robot.voice.denoise`) into a twin engine, with its own thresholds.
"""

from __future__ import annotations

import contextlib
import io
import threading
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from sage_robot.core.audio import FRAME_S, FRAME_SAMPLES, SAMPLE_RATE_HZ
from sage_robot.core.errors import ConfigError
from sage_robot.voice.audio_io import Framer, to_int16
from sage_robot.voice.denoise import NoiseSuppressor
from sage_robot.voice.wake_head import HEAD_FRAMES, WakeHead, load_head

WARMUP_SAMPLES = SAMPLE_RATE_HZ * 4  # 4 s: openWakeWord's feature history at start-up
WARMUP_SEED = 1234  # seeds the start-up history so every run scores the same
WARMUP_AMPLITUDE = 1000  # int16 peak of that start-up noise (openWakeWord's value)
DEFAULT_REFRACTORY_S = 2.0
DEFAULT_PATIENCE = 2  # frames in a row over threshold: a real wake word gives 5-14, a spike 1
DEFAULT_SMOOTHING = 1  # frames averaged before the threshold (1: the frame's own score)
DENOISED_SUFFIX = "/denoised"  # key suffix of the denoised path's scores in max_scores etc.
HEAD_SUFFIX = "/head"  # key suffix of the head path's scores
DEFAULT_HEAD_THRESHOLD = 0.9
DEFAULT_HEAD_GATE = 0.02  # the model's own smoothed score a head needs beside it
# A model loaded by path keeps openWakeWord's own conventions (its README's default
# threshold, every frame judged alone), which its author tuned it for, unless the
# profile names it in wake_model_thresholds / _patience / _smoothing.
CUSTOM_THRESHOLD = 0.5
CUSTOM_PATIENCE = 1  # frames
CUSTOM_SMOOTHING = 1  # frames


class WakeEngine(Protocol):
    """Scores 80 ms frames of 16 kHz int16 audio for each wake model."""

    @property
    def names(self) -> tuple[str, ...]: ...

    def score(self, frame: np.ndarray) -> dict[str, float]:
        """One frame of exactly ``FRAME_SAMPLES`` samples → score 0..1 per model."""
        ...

    def reset(self) -> None:
        """Forget the audio history (a new stream starts)."""
        ...


def _bundled_dir() -> Path:
    try:
        import openwakeword
    except ImportError:
        raise ConfigError(
            "wake words need openWakeWord: pip install 'sage-robot[voice-gpl]'"
        ) from None
    return Path(openwakeword.__file__).parent / "resources" / "models"


def bundled_wake_models() -> dict[str, Path]:
    """Names of the pre-trained ONNX wake models that ship with openWakeWord."""
    skip = ("melspectrogram", "embedding_model", "silero_vad")
    out = {}
    for p in sorted(_bundled_dir().glob("*.onnx")):
        if p.stem not in skip:
            out[p.stem.rsplit("_v", 1)[0]] = p
    return out


def is_custom_model(spec: str) -> bool:
    """A model given by path (``/path/hey_sage.onnx``), not by a bundled name."""
    return spec.endswith(".onnx") or "/" in spec


def resolve_wake_model(spec: str) -> tuple[str, Path]:
    """``"hey_jarvis"`` or ``"/path/hey_sage.onnx"`` → (name, path to an ONNX file)."""
    if is_custom_model(spec):
        path = Path(spec).expanduser()
        if not path.is_file():
            raise ConfigError(f"wake model {spec}: no such file")
        if path.suffix != ".onnx":
            raise ConfigError(f"wake model {spec}: only .onnx models are supported")
        return path.stem.rsplit("_v", 1)[0] if "_v0" in path.stem else path.stem, path
    models = bundled_wake_models()
    if spec not in models:
        raise ConfigError(
            f"unknown wake model {spec!r}; bundled: {', '.join(models)} (or give an .onnx path)"
        )
    return spec, models[spec]


class OpenWakeWordEngine:
    """openWakeWord with the ONNX runtime, every model loaded by path (never downloaded)."""

    def __init__(self, specs: Sequence[str]) -> None:
        if not specs:
            raise ConfigError("give at least one wake model")
        resolved = [resolve_wake_model(s) for s in specs]
        names = [n for n, _ in resolved]
        if len(set(names)) != len(names):
            raise ConfigError(f"wake models have the same name twice: {names}")
        base = _bundled_dir()
        try:
            from openwakeword.model import Model
        except ImportError:
            raise ConfigError("wake words need openwakeword and onnxruntime installed") from None
        with contextlib.redirect_stdout(io.StringIO()):  # the library prints its model list
            try:
                self._model = Model(
                    wakeword_models=[str(p) for _, p in resolved],
                    inference_framework="onnx",
                    melspec_model_path=str(base / "melspectrogram.onnx"),
                    embedding_model_path=str(base / "embedding_model.onnx"),
                )
            except Exception as exc:  # onnxruntime's errors for a broken file
                raise ConfigError(f"cannot load wake models {list(specs)}: {exc}") from None
        # openWakeWord keys its models by file stem; map them to our names.
        self._keys = dict(zip(names, self._model.models.keys(), strict=True))
        self._names = tuple(names)
        self.custom_names = frozenset(n for n, spec in zip(names, specs, strict=True)
                                      if is_custom_model(spec))  # fmt: skip
        pre = self._model.preprocessor
        rng = np.random.default_rng(WARMUP_SEED)
        warm = rng.integers(-WARMUP_AMPLITUDE, WARMUP_AMPLITUDE, WARMUP_SAMPLES).astype(np.int16)
        self._initial_features = pre._get_embeddings(warm)
        self._specs = tuple(specs)
        self._twin: OpenWakeWordEngine | None = None
        # One engine serves every pipeline built on the loaded models: a pipeline built again
        # resets it while the last frame of the one stopped before may still be scored in a
        # worker thread. openWakeWord's buffers are not thread-safe; a reset half-way through
        # a prediction could leave the old audio (a wake word) in them.
        self._lock = threading.Lock()
        self.reset()

    def features(self) -> np.ndarray:
        """The window of speech embeddings the models scored last: (16, 96)."""
        pre: Any = self._model.preprocessor
        with self._lock:
            return np.asarray(pre.get_features(HEAD_FRAMES)[0], dtype=np.float64)

    def twin(self) -> OpenWakeWordEngine:
        """A second engine with the same models and its own audio history (made once)."""
        if self._twin is None:
            self._twin = OpenWakeWordEngine(self._specs)
        return self._twin

    @property
    def names(self) -> tuple[str, ...]:
        return self._names

    def reset(self) -> None:
        pre: Any = self._model.preprocessor
        with self._lock:
            pre.raw_data_buffer.clear()
            pre.melspectrogram_buffer = np.ones((76, 32))  # openWakeWord's initial mel state
            pre.accumulated_samples = 0
            pre.raw_data_remainder = np.empty(0)
            pre.feature_buffer = self._initial_features.copy()
            self._model.reset()

    def score(self, frame: np.ndarray) -> dict[str, float]:
        if len(frame) != FRAME_SAMPLES:
            raise ValueError(f"a wake frame is {FRAME_SAMPLES} samples, got {len(frame)}")
        with self._lock:
            raw = self._model.predict(to_int16(frame))
        return {name: float(raw[key]) for name, key in self._keys.items()}


@dataclass(frozen=True)
class Detection:
    """A wake word heard: ``time_s`` is the end of the frame, from the stream's start."""

    model: str
    score: float
    time_s: float


class WakeDetector:
    """Smoothing, threshold, patience and refractory over an engine; accepts any chunks.

    Each model's score is first averaged over its last ``smoothing`` frames (a wake word
    in noise scores moderately over several frames, a confusable word spikes for one).
    A detection needs ``patience`` frames in a row with that average at or over the
    threshold (isolated one-frame spikes on words like "Alex" are not wake words).
    After a detection the same model is ignored for ``refractory_s`` (the score stays
    high for several frames while the phrase ends; one utterance is one detection).

    ``denoised`` (an engine of the same models with its own state) adds the second path:
    frames through a :class:`NoiseSuppressor` (16 ms later) into it, smoothed and
    patient the same way, against ``denoised_thresholds`` (only the models named there;
    None: every model at its first-path threshold). Its scores appear under
    ``name + DENOISED_SUFFIX``.

    ``heads`` (model name → :class:`WakeHead`) adds the head path: each head scores the
    engine's embedding window (the engine needs ``features()``), smoothed like its model,
    against ``head_threshold``, and passes only while the model's own smoothed score is at
    least ``head_gate``. Its scores appear under ``name + HEAD_SUFFIX``.
    """

    def __init__(
        self,
        engine: WakeEngine,
        threshold: float = 0.6,
        refractory_s: float = DEFAULT_REFRACTORY_S,
        keep_scores: bool = False,
        patience: int = DEFAULT_PATIENCE,
        model_thresholds: Mapping[str, float] | None = None,
        model_patience: Mapping[str, int] | None = None,
        smoothing: int = DEFAULT_SMOOTHING,
        model_smoothing: Mapping[str, int] | None = None,
        denoised: WakeEngine | None = None,
        denoised_thresholds: Mapping[str, float] | None = None,
        heads: Mapping[str, WakeHead] | None = None,
        head_threshold: float = DEFAULT_HEAD_THRESHOLD,
        head_gate: float = DEFAULT_HEAD_GATE,
    ) -> None:
        self.engine, self.threshold, self.refractory_s = engine, threshold, refractory_s
        # A detector starts on fresh audio: an engine shared with an earlier detector (a
        # pipeline built again on the same loaded models) still holds that one's last
        # 1.3 s, and a wake word in it would wake this one at once.
        engine.reset()
        if denoised is not None and (denoised is engine or set(denoised.names) != set(engine.names)):
            raise ValueError("the denoised path needs its own engine with the same models")
        self.denoised = denoised
        self.suppressor = NoiseSuppressor() if denoised is not None else None
        if denoised is not None:
            denoised.reset()  # the second path starts fresh, like its suppressor
        self.patience = patience
        # Per model (name → value); models not named use ``threshold`` / ``patience``.
        self.thresholds = {n: (model_thresholds or {}).get(n, threshold) for n in engine.names}
        self.patiences = {n: (model_patience or {}).get(n, patience) for n in engine.names}
        self.smoothings = {n: (model_smoothing or {}).get(n, smoothing) for n in engine.names}
        for what, values in (("patience", self.patiences), ("smoothing", self.smoothings)):
            for name, p in [("", patience if what == "patience" else smoothing), *values.items()]:
                if p < 1:
                    raise ValueError(f"{what} must be >= 1 frame, got {p} {name}".rstrip())
        self._recent: dict[str, deque[float]] = {}  # last scores per path key
        self.denoised_thresholds = {} if denoised is None else dict(self.thresholds) \
            if denoised_thresholds is None \
            else {n: th for n, th in denoised_thresholds.items() if n in engine.names}  # fmt: skip
        self.heads = {n: h for n, h in (heads or {}).items() if n in engine.names}
        if self.heads and not callable(getattr(engine, "features", None)):
            raise ValueError("wake heads need an engine that exposes its embeddings (features())")
        self.head_thresholds = dict.fromkeys(self.heads, head_threshold)
        self.head_threshold_value, self.head_gate = head_threshold, head_gate
        for name, th in [*self.thresholds.items(), *self.denoised_thresholds.items(),
                         *self.head_thresholds.items(), ("head gate", head_gate)]:  # fmt: skip
            if not 0 <= th <= 1:
                raise ValueError(f"wake threshold of {name} must be in 0..1, got {th}")
        self._run: dict[str, int] = {}  # frames in a row over threshold, per path key
        self.keep_scores = keep_scores
        self.scores: list[dict[str, float]] = []  # every frame's scores, with keep_scores
        self._framer = Framer(FRAME_SAMPLES)
        self.frames = 0
        self._last: dict[str, float] = {}
        self._smoothed: dict[str, float] = {}  # this frame's smoothed score per path key
        self.max_scores: dict[str, float] = dict.fromkeys(self._keys(), 0.0)  # raw frame scores
        self.max_smoothed: dict[str, float] = dict.fromkeys(self._keys(), 0.0)
        self.max_head_gated = {n + HEAD_SUFFIX: 0.0 for n in self.heads}  # smoothed, gate open
        self.last_scores: dict[str, float] = dict.fromkeys(engine.names, 0.0)

    def _keys(self) -> list[str]:
        keys = list(self.engine.names)
        return keys + [n + DENOISED_SUFFIX for n in self.denoised_thresholds] \
            + [n + HEAD_SUFFIX for n in self.heads]  # fmt: skip

    @classmethod
    def from_settings(cls, engine: WakeEngine, s: Any, threshold: float | None = None) -> WakeDetector:
        """The profile's detector (``voice`` settings); ``threshold`` overrides every model's.

        With ``s.wake_denoise`` the denoised path runs on ``engine.twin()`` (an engine
        without ``twin`` gets none); ``s.wake_heads`` names the heads (an engine without
        ``features`` gets none; their threshold is ``s.wake_head_threshold`` always).
        Models the engine loaded by path (its ``custom_names``) default to openWakeWord's
        conventions (``CUSTOM_THRESHOLD``, one frame, no smoothing) where the profile does
        not name them."""
        twin = getattr(engine, "twin", None) if s.wake_denoise else None
        custom: frozenset[str] = getattr(engine, "custom_names", frozenset())
        thresholds = {**dict.fromkeys(custom, CUSTOM_THRESHOLD), **s.wake_model_thresholds}
        patience = {**dict.fromkeys(custom, CUSTOM_PATIENCE), **s.wake_model_patience}
        smoothing = {**dict.fromkeys(custom, CUSTOM_SMOOTHING), **s.wake_model_smoothing}
        use_heads = callable(getattr(engine, "features", None))
        heads = {m: load_head(h) for m, h in s.wake_heads.items()} if use_heads else None
        return cls(engine, s.wake_threshold if threshold is None else threshold,
                   s.wake_refractory_s, patience=s.wake_patience_frames,
                   model_thresholds=thresholds if threshold is None else None,
                   model_patience=patience, smoothing=s.wake_smoothing_frames,
                   model_smoothing=smoothing, denoised=twin() if twin else None,
                   denoised_thresholds=s.wake_denoise_thresholds if threshold is None else None,
                   heads=heads, head_threshold=s.wake_head_threshold, head_gate=s.wake_head_gate)  # fmt: skip

    @property
    def time_s(self) -> float:
        return self.frames * FRAME_S

    def reset(self) -> None:
        self.engine.reset()
        if self.denoised is not None and self.suppressor is not None:
            self.denoised.reset()
            self.suppressor.reset()
        self._framer.reset()
        self.frames = 0
        self._last.clear()
        self._run.clear()
        self._recent.clear()
        self._smoothed.clear()
        self.max_scores = dict.fromkeys(self._keys(), 0.0)
        self.max_smoothed = dict.fromkeys(self._keys(), 0.0)
        self.max_head_gated = {n + HEAD_SUFFIX: 0.0 for n in self.heads}

    def feed(self, chunk: np.ndarray) -> list[Detection]:
        """Push audio; returns the detections completed by it."""
        found = []
        for frame in self._framer.push(chunk):
            found.extend(self.feed_frame(frame))
        return found

    def feed_frame(self, frame: np.ndarray) -> list[Detection]:
        scores = self.engine.score(frame)
        paths = [(scores, "", self.thresholds)]
        if self.denoised is not None and self.suppressor is not None:
            clean = self.suppressor.process(frame)  # a whole frame in, a whole frame out
            paths.append((self.denoised.score(clean), DENOISED_SUFFIX, self.denoised_thresholds))
        if self.heads:
            window = self.engine.features()  # type: ignore[attr-defined]  # checked in __init__
            heads = {n: h.score(window) for n, h in self.heads.items()}
            paths.append((heads, HEAD_SUFFIX, self.head_thresholds))
        self.frames += 1
        self.last_scores = scores
        if self.keep_scores:
            self.scores.append(scores)
        found = []
        t = self.time_s
        for name in scores:
            passed = [s for sc, suffix, ths in paths if name in ths
                      and (s := self._path(name, name + suffix, sc[name], ths)) is not None
                      and (suffix != HEAD_SUFFIX or self._smoothed[name] >= self.head_gate)]  # fmt: skip
            if not passed:
                continue
            last = self._last.get(name)
            if last is not None and t - last < self.refractory_s:
                continue
            self._last[name] = t
            found.append(Detection(name, max(passed), t))
        for name in self.heads:  # what the gate let through: the head's margin to its threshold
            if self._smoothed[name] >= self.head_gate:
                key = name + HEAD_SUFFIX
                self.max_head_gated[key] = max(self.max_head_gated[key], self._smoothed[key])
        return found

    def _path(self, name: str, key: str, raw: float, thresholds: Mapping[str, float]) -> float | None:
        """One path's frame score → its smoothed score if it passes (threshold, patience)."""
        self.max_scores[key] = max(self.max_scores.get(key, 0.0), raw)
        recent = self._recent.setdefault(key, deque(maxlen=self.smoothings.get(name, 1)))
        recent.append(raw)
        s = sum(recent) / len(recent)  # the mean of the last ``smoothing`` frames
        self._smoothed[key] = s
        self.max_smoothed[key] = max(self.max_smoothed.get(key, 0.0), s)
        over = s >= thresholds.get(name, self.threshold)
        self._run[key] = self._run.get(key, 0) + 1 if over else 0
        return s if self._run[key] >= self.patiences.get(name, self.patience) else None
