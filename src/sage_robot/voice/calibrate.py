"""Pick a wake model's threshold and patience from the owners' own recordings.

``sage voice wake calibrate --model hey_sage.onnx --positives DIR --negatives DIR``:
every positive clip (a wake phrase, any format :func:`load_audio` reads) is scored with
1 s of silence either side, every negative file (anything but the wake phrase: talk,
noise, the robot's rooms) from a fresh start, frame by frame, once. The detector's rule
(mean over ``smoothing`` frames, ``patience`` frames in a row at or over the threshold,
``refractory_s`` between detections: :class:`~sage_robot.voice.wake.WakeDetector`) is then
replayed on those scores for every candidate setting, which is exact and cheap.

The choice: among the settings whose false accepts per hour of negatives stay within
the target, the fewest false rejects (then the fewest false accepts, then the shortest
patience); its threshold is the middle of the band of thresholds that give the same
counts, so neither a slightly louder positive nor a slightly more confusable negative
flips the result. When no setting meets the target, the one with the fewest false
accepts is reported with ``meets_target`` false.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from sage_robot.core.audio import FRAME_S, FRAME_SAMPLES, SAMPLE_RATE_HZ
from sage_robot.core.errors import ConfigError
from sage_robot.voice.wake import DEFAULT_REFRACTORY_S, WakeEngine

PAD_S = 1.0  # silence around each positive clip, as a phrase arrives after quiet
THRESHOLDS = tuple(round(0.05 + 0.01 * i, 2) for i in range(91))  # 0.05 .. 0.95
PATIENCES = (1, 2, 3, 4)  # frames
DEFAULT_MAX_FA_PER_HOUR = 1.0
AUDIO_SUFFIXES = (".wav", ".raw", ".flac", ".ogg", ".mp3", ".webm", ".m4a")
SECONDS_PER_HOUR = 3600.0


@dataclass(frozen=True)
class Calibration:
    """The chosen setting and what it does on the recordings."""

    model: str
    threshold: float
    patience: int  # frames
    smoothing: int  # frames (the profile's, not searched)
    positives: int
    false_rejects: int
    false_reject_rate: float
    negative_hours: float
    false_accepts: int
    false_accepts_per_hour: float
    max_fa_per_hour: float  # the target
    meets_target: bool
    band: tuple[float, float]  # thresholds that give the same counts at this patience
    negatives_best: float  # the negatives' best score held for ``patience`` frames
    positives_worst: float  # the lowest best-held score among the positives

    def as_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["band"] = list(self.band)
        return {k: round(v, 4) if isinstance(v, float) else v for k, v in out.items()}


def audio_files(folder: str | Path, what: str) -> list[Path]:
    """The audio files of a folder (sorted), or a clear error."""
    path = Path(folder).expanduser()
    if not path.is_dir():
        raise ConfigError(f"{what} {folder}: not a folder")
    files = sorted(p for p in path.iterdir() if p.suffix.lower() in AUDIO_SUFFIXES)
    if not files:
        raise ConfigError(f"{what} {folder}: no audio files ({', '.join(AUDIO_SUFFIXES)})")
    return files


def frame_scores(engine: WakeEngine, model: str, pcm: np.ndarray) -> np.ndarray:
    """One model's raw score per 80 ms frame of ``pcm``, from a fresh engine state."""
    engine.reset()
    n = len(pcm) // FRAME_SAMPLES
    return np.array([engine.score(pcm[i * FRAME_SAMPLES : (i + 1) * FRAME_SAMPLES])[model]
                     for i in range(n)], dtype=np.float64)  # fmt: skip


def padded(pcm: np.ndarray) -> np.ndarray:
    pad = np.zeros(round(PAD_S * SAMPLE_RATE_HZ), dtype=np.int16)
    return np.concatenate([pad, np.asarray(pcm, dtype=np.int16), pad])


def held(scores: np.ndarray, smoothing: int, patience: int) -> np.ndarray:
    """Per frame, the lowest smoothed score of the last ``patience`` frames (0 before):
    a frame passes a threshold with that patience exactly when this is >= it."""
    n = len(scores)
    if n == 0:
        return scores
    # The mean of the last ``smoothing`` frames (fewer at the start), summed oldest first
    # as the detector sums them, so both give the same bits.
    total, count = np.zeros(n), np.zeros(n)
    for lag in range(min(smoothing, n) - 1, -1, -1):
        total[lag:] += scores[: n - lag]
        count[lag:] += 1
    smooth = total / count
    out = np.zeros(n)
    if n >= patience:
        windows = np.lib.stride_tricks.sliding_window_view(smooth, patience)
        out[patience - 1 :] = windows.min(axis=1)
    return out


def count_detections(h: np.ndarray, threshold: float, refractory_s: float) -> int:
    """Detections in one stream of held scores, with the refractory between them."""
    count, last = 0, None
    for i in np.flatnonzero(h >= threshold):
        t = (int(i) + 1) * FRAME_S  # the detector's time stamp of the frame, to the bit
        if last is None or not t - last < refractory_s:
            count, last = count + 1, t
    return count


def _band(ok: np.ndarray, i: int) -> tuple[int, int]:
    """The run of True in ``ok`` around index ``i``."""
    lo, hi = i, i
    while lo > 0 and ok[lo - 1]:
        lo -= 1
    while hi < len(ok) - 1 and ok[hi + 1]:
        hi += 1
    return lo, hi


def choose(
    model: str,
    positives: Sequence[np.ndarray],
    negatives: Sequence[np.ndarray],
    smoothing: int = 1,
    refractory_s: float = DEFAULT_REFRACTORY_S,
    max_fa_per_hour: float = DEFAULT_MAX_FA_PER_HOUR,
) -> Calibration:
    """The setting for ``model`` from its raw frame scores on positive clips (padded)
    and negative streams (see module doc)."""
    if not positives or not negatives:
        raise ConfigError("calibration needs positive clips and negative recordings")
    hours = sum(len(s) for s in negatives) * FRAME_S / SECONDS_PER_HOUR
    if hours <= 0:
        raise ConfigError("the negative recordings are shorter than one 80 ms frame")
    ths = np.array(THRESHOLDS)
    table = []  # per patience: (false rejects, false accepts) per threshold, and the held maxima
    for p in PATIENCES:
        pos_best = np.array([held(s, smoothing, p).max(initial=0.0) for s in positives])
        neg_held = [held(s, smoothing, p) for s in negatives]
        fr = (pos_best[None, :] < ths[:, None]).sum(axis=1)
        fa = np.array([sum(count_detections(h, t, refractory_s) for h in neg_held) for t in ths])
        table.append((p, fr, fa, pos_best, max(h.max(initial=0.0) for h in neg_held)))
    allowed = [(int(fr[i]), int(fa[i]), p, i) for p, fr, fa, _, _ in table for i in range(len(ths))
               if fa[i] / hours <= max_fa_per_hour + 1e-12]  # fmt: skip
    meets = bool(allowed)
    if not allowed:  # nothing meets the target: the fewest false accepts
        allowed = [(int(fa[i]), int(fr[i]), p, i) for p, fr, fa, _, _ in table for i in range(len(ths))]
    _, _, p_best, i_best = min(allowed)
    p, fr, fa, pos_best, neg_best = next(row for row in table if row[0] == p_best)
    lo, hi = _band((fr == fr[i_best]) & (fa == fa[i_best]), i_best)
    mid = (lo + hi) // 2
    return Calibration(
        model=model, threshold=float(ths[mid]), patience=p, smoothing=smoothing,
        positives=len(positives), false_rejects=int(fr[mid]),
        false_reject_rate=float(fr[mid]) / len(positives), negative_hours=hours,
        false_accepts=int(fa[mid]), false_accepts_per_hour=float(fa[mid]) / hours,
        max_fa_per_hour=max_fa_per_hour, meets_target=meets,
        band=(float(ths[lo]), float(ths[hi])), negatives_best=float(neg_best),
        positives_worst=float(pos_best.min()),
    )  # fmt: skip


def calibrate_files(
    engine: WakeEngine,
    model: str,
    positives: Sequence[Path],
    negatives: Sequence[Path],
    smoothing: int = 1,
    refractory_s: float = DEFAULT_REFRACTORY_S,
    max_fa_per_hour: float = DEFAULT_MAX_FA_PER_HOUR,
) -> Calibration:
    """Score the files with ``engine`` (which has ``model``) and :func:`choose`."""
    from sage_robot.voice.audio_io import load_audio

    if model not in engine.names:
        raise ConfigError(f"wake model {model!r} is not loaded (loaded: {', '.join(engine.names)})")
    pos = [frame_scores(engine, model, padded(load_audio(f))) for f in positives]
    neg = [frame_scores(engine, model, load_audio(f)) for f in negatives]
    return choose(model, pos, neg, smoothing, refractory_s, max_fa_per_hour)


def profile_update(voice: Any, cal: Calibration) -> dict[str, Any]:
    """The ``voice:`` keys to write: the profile's per-model maps with this model's entry."""
    return {
        "wake_model_thresholds": {**voice.wake_model_thresholds, cal.model: cal.threshold},
        "wake_model_patience": {**voice.wake_model_patience, cal.model: cal.patience},
    }
