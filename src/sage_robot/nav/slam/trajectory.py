"""Trajectory error after the best alignment (the absolute trajectory error of Sturm et al.,
2012, as the TUM RGB-D benchmark computes it).

An estimated trajectory is compared with the true one after the rigid motion (and, for the
scale-aligned variant, the scale) that brings it closest in the least-squares sense,
found in closed form (Umeyama, 1991). The rigid variant is the standard ATE; the scale it
would take on top tells how much too long or short the estimate reads the travel (a
uniform scale error, which loop closures cannot remove).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MIN_POINTS = 2  # an alignment needs two positions at least


@dataclass(frozen=True)
class Alignment:
    rotation_rad: float
    translation: tuple[float, float]
    scale: float  # 1.0 for a rigid alignment
    rmse_m: float  # of the aligned positions

    def apply(self, pose: tuple[float, float, float]) -> tuple[float, float, float]:
        """``pose`` (x, y m; theta rad) moved by this alignment (rotation, scale, translation)."""
        c, s = np.cos(self.rotation_rad), np.sin(self.rotation_rad)
        x, y, th = pose
        return (
            float(self.scale * (c * x - s * y) + self.translation[0]),
            float(self.scale * (s * x + c * y) + self.translation[1]),
            float(th + self.rotation_rad),
        )


def align(est: np.ndarray, true: np.ndarray, with_scale: bool = False) -> Alignment:
    """The rotation, translation (and scale) taking ``est`` (N×2 positions) closest to
    ``true`` (N×2), and the RMSE of the aligned positions. Raises ValueError on shapes that
    cannot be aligned."""
    est, true = np.asarray(est, dtype=float), np.asarray(true, dtype=float)
    if est.shape != true.shape or est.ndim != 2 or est.shape[1] != 2 or len(est) < MIN_POINTS:
        raise ValueError(
            f"align: need two N×2 position arrays with N ≥ {MIN_POINTS}, got {est.shape}, {true.shape}"
        )
    mu_e, mu_t = est.mean(axis=0), true.mean(axis=0)
    de, dt = est - mu_e, true - mu_t
    cov = dt.T @ de / len(est)
    u, d, vt = np.linalg.svd(cov)
    sign = np.eye(2)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:  # a reflection: take the nearest rotation
        sign[1, 1] = -1.0
    rot = u @ sign @ vt
    var_e = float((de**2).sum() / len(est))
    scale = float(np.trace(np.diag(d) @ sign) / var_e) if with_scale and var_e > 0 else 1.0
    shift = mu_t - scale * rot @ mu_e
    aligned = scale * est @ rot.T + shift
    rmse = float(np.sqrt((np.hypot(*(aligned - true).T) ** 2).mean()))
    return Alignment(float(np.arctan2(rot[1, 0], rot[0, 0])), (float(shift[0]), float(shift[1])), scale, rmse)
