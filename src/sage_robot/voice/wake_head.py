"""Wake-word heads: small classifiers on openWakeWord's speech embeddings.

openWakeWord turns audio into a 96-number speech embedding every 80 ms; a wake model
scores the last 16 of them. A head is a second, much smaller scorer of that same window,
trained by ``scripts/train_wake_head.py`` on synthetic speech in heavy noise (white,
pink, brown noise and the babble of other talkers at -2..20 dB SNR), where the bundled
model's score collapses. It costs a dot product per frame: the embeddings are the ones
the engine has already computed.

The bundled ``hey_jarvis_noise`` head is a logistic regression on the standardised
16 x 96 window. A head file is an ``.npz`` with ``mean`` and ``scale`` (the window's
standardisation, 16 x 96 each), ``weights`` (16 x 96) and ``bias`` (a scalar): score =
sigmoid(sum(weights * (window - mean) / scale) + bias).
"""

from __future__ import annotations

import functools
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from sage_robot.core.errors import ConfigError

HEAD_FRAMES = 16  # embeddings per window (1.28 s), as openWakeWord's models
EMBEDDING_SIZE = 96  # numbers per openWakeWord speech embedding
HEADS_DIR = Path(__file__).resolve().parent.parent / "data" / "wake"


class WakeHead:
    """A logistic-regression scorer of one window of speech embeddings."""

    def __init__(self, name: str, mean: np.ndarray, scale: np.ndarray, weights: np.ndarray,
                 bias: float) -> None:  # fmt: skip
        shape = (HEAD_FRAMES, EMBEDDING_SIZE)
        for what, a in (("mean", mean), ("scale", scale), ("weights", weights)):
            if a.shape != shape:
                raise ConfigError(f"wake head {name}: {what} must be {shape}, got {a.shape}")
            if not np.all(np.isfinite(a)):
                raise ConfigError(f"wake head {name}: {what} has non-finite numbers")
        if np.any(scale <= 0) or not np.isfinite(bias):
            raise ConfigError(f"wake head {name}: scale must be > 0 and bias finite")
        self.name = name
        # Folded: w . (x - mean) / scale + b  ==  (w / scale) . x + (b - (w / scale) . mean)
        self._w = (weights / scale).astype(np.float64)
        self._b = float(bias - np.sum(self._w * mean))

    def score(self, window: np.ndarray) -> float:
        """A (16, 96) window of embeddings → the probability it ends a wake word."""
        if window.shape != (HEAD_FRAMES, EMBEDDING_SIZE):
            raise ValueError(f"a head window is {(HEAD_FRAMES, EMBEDDING_SIZE)}, got {window.shape}")
        z = float(np.sum(self._w * window)) + self._b
        return float(1.0 / (1.0 + np.exp(-np.clip(z, -60.0, 60.0))))


def bundled_heads() -> dict[str, Path]:
    """The heads that ship with SAGE (``data/wake/*.npz``), by name."""
    return {p.stem: p for p in sorted(HEADS_DIR.glob("*.npz"))}


def resolve_head(spec: str) -> tuple[str, Path]:
    """``"hey_jarvis_noise"`` or ``"/path/head.npz"`` → (name, path)."""
    if spec.endswith(".npz") or "/" in spec:
        path = Path(spec).expanduser()
        if not path.is_file():
            raise ConfigError(f"wake head {spec}: no such file")
        return path.stem, path
    heads = bundled_heads()
    if spec not in heads:
        raise ConfigError(f"unknown wake head {spec!r}; bundled: {', '.join(heads) or 'none'} "
                          "(or give an .npz path)")  # fmt: skip
    return spec, heads[spec]


@functools.lru_cache(maxsize=16)
def load_head(spec: str) -> WakeHead:
    """Load a head by bundled name or path (cached: heads are immutable)."""
    name, path = resolve_head(spec)
    try:
        with np.load(path, allow_pickle=False) as z:
            parts = {k: np.asarray(z[k], dtype=np.float64) for k in ("mean", "scale", "weights", "bias")}
    except KeyError as exc:
        raise ConfigError(f"wake head {path}: missing array {exc}") from None
    except (OSError, ValueError, zipfile.BadZipFile) as exc:
        raise ConfigError(f"wake head {path}: not a head file ({exc})") from None
    if parts["bias"].size != 1:
        raise ConfigError(f"wake head {path}: bias must be one number")
    return WakeHead(name, parts["mean"], parts["scale"], parts["weights"], float(parts["bias"].ravel()[0]))


def save_head(path: Path, mean: np.ndarray, scale: np.ndarray, weights: np.ndarray, bias: float,
              **about: str) -> None:  # fmt: skip
    """Write a head file (``about``: short strings kept beside the arrays, e.g. how it was trained)."""
    WakeHead(path.stem, mean, scale, weights, bias)  # validates
    parts = {"mean": mean, "scale": scale, "weights": weights, "bias": [bias]}
    arrays: dict[str, Any] = {k: np.asarray(a, np.float32) for k, a in parts.items()}
    arrays.update({f"about_{k}": np.array(v) for k, v in about.items()})
    np.savez_compressed(path, **arrays)
