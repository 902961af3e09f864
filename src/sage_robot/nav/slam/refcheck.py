"""How a relations file was made: is its reference odometry plus a correction on a grid?

The MIT CSAIL relations of Kümmerle et al. 2009 are not continuous: for a short relation (scans
a few apart) the reference translation minus the odometry's (both in the frame of the first
pose, m) is always a vector of a square 5 cm grid — length 0, 5, 7.07, 10, 11.18 cm … — and
the reference rotation minus the odometry's is a multiple of 0.25° (plus a constant). The
reference was made by a search on a grid around the odometry, so it carries that grid's
rounding: a perfect estimator disagrees with it by the rounding error.

:func:`reference_quantization` measures this for any relations file (m, rad in; the result in m
and degrees), and estimates that floor: the mean distance between an estimate's offset from
the odometry and the nearest grid point, averaged over grid orientations (the grid lies in the
reference's world frame, whose heading relative to ours is not known).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

SHORT_GAP_SCANS = 6  # relations between scans at most this far apart count as short
EQUAL_TOLERANCE_M = 1e-4  # a reference translation this close to the odometry's "equals" it
GRID_TOLERANCE = 0.02  # |offset|²/step² within this of an integer a²+b²: on the grid
ROT_TOLERANCE_DEG = 0.01  # rotation offsets within this of the common residue: on the grid
FLOOR_ORIENTATIONS = 18  # grid orientations averaged for the floor (0..90°)
MAX_GRID_CELLS = 8  # offsets up to this many cells are looked for


@dataclass(frozen=True)
class ReferenceQuantization:
    relations: int  # short relations looked at
    equal_odometry: float  # fraction whose reference translation equals the odometry's
    on_grid: float  # fraction whose offset from the odometry has a grid length
    rot_on_grid: float  # fraction whose rotation offset is on the rotation grid
    grid_m: float
    rot_grid_deg: float
    estimate_error_m: float  # mean translational error of the estimate on these relations
    floor_m: float  # mean error a perfect estimator with the estimate's offsets would get
    # Per axis (x, y of the first pose's frame, m): the part of the estimate's offset from the
    # odometry that the reference's does not share, and the part of the reference's beyond
    # the rounding that the estimate's does not share (covariance split; assumes independent
    # errors, so an error both scan matchers make counts as truth).
    estimate_noise_m: tuple[float, float] = (0.0, 0.0)
    reference_noise_m: tuple[float, float] = (0.0, 0.0)

    def as_dict(self) -> dict[str, float | int | list[float]]:
        return {
            "short_relations": self.relations,
            "short_trans_error_mean_m": round(self.estimate_error_m, 5),
            "reference_equal_odometry": round(self.equal_odometry, 3),
            "reference_on_grid": round(self.on_grid, 3),
            "reference_rot_on_grid": round(self.rot_on_grid, 3),
            "reference_grid_m": self.grid_m,
            "reference_rot_grid_deg": self.rot_grid_deg,
            "reference_rounding_floor_m": round(self.floor_m, 5),
            "estimate_noise_xy_m": [round(v, 4) for v in self.estimate_noise_m],
            "reference_noise_xy_m": [round(v, 4) for v in self.reference_noise_m],
        }


def _grid_lengths() -> np.ndarray:
    """Squared lengths (in cells²) of the vectors of a square grid: 0, 1, 2, 4, 5, 8, …"""
    a = np.arange(MAX_GRID_CELLS + 1)
    return np.unique((a[:, None] ** 2 + a[None, :] ** 2).ravel()).astype(np.float64)


def rounding_error(offsets: np.ndarray, step_m: float, orientations: int = FLOOR_ORIENTATIONS) -> float:
    """Mean distance (m) from 2-D ``offsets`` (N, 2) to the nearest point of a ``step_m`` grid,
    averaged over grid orientations 0..90°."""
    if len(offsets) == 0:
        return 0.0
    total = 0.0
    for phi in np.linspace(0.0, math.pi / 2, orientations, endpoint=False):
        c, s = math.cos(phi), math.sin(phi)
        g = offsets @ np.array([[c, -s], [s, c]]) / step_m
        total += float(np.hypot(*(g - np.round(g)).T).mean()) * step_m
    return total / orientations


def reference_quantization(
    reference: np.ndarray,
    odometry: np.ndarray,
    estimate: np.ndarray,
    grid_m: float = 0.05,
    rot_grid_deg: float = 0.25,
) -> ReferenceQuantization:
    """Compare short relations' reference, odometry and estimated relative poses.

    Each argument is (N, 3): relative poses (dx, dy m in the first pose's frame; dθ rad), row k
    of each for the same relation.
    """
    reference, odometry, estimate = (
        np.asarray(a, dtype=np.float64).reshape(-1, 3) for a in (reference, odometry, estimate)
    )
    n = len(reference)
    if n == 0:
        return ReferenceQuantization(0, 0.0, 0.0, 0.0, grid_m, rot_grid_deg, 0.0, 0.0)
    off = reference[:, :2] - odometry[:, :2]
    length = np.hypot(*off.T)
    cells2 = (length / grid_m) ** 2
    lengths = _grid_lengths()
    nearest = lengths[np.abs(cells2[:, None] - lengths[None, :]).argmin(axis=1)]
    on_grid = np.abs(cells2 - nearest) < GRID_TOLERANCE
    dth = np.degrees((reference[:, 2] - odometry[:, 2] + math.pi) % (2 * math.pi) - math.pi)
    residue = dth % rot_grid_deg
    # the common residue on the circle of circumference rot_grid_deg
    angle = residue / rot_grid_deg * 2 * math.pi
    common = (math.atan2(np.sin(angle).mean(), np.cos(angle).mean()) / (2 * math.pi)) * rot_grid_deg
    gap = np.abs((residue - common + rot_grid_deg / 2) % rot_grid_deg - rot_grid_deg / 2)
    est_off = estimate[:, :2] - odometry[:, :2]
    est_noise, ref_noise = _covariance_split(est_off, off, grid_m**2 / 12.0)
    return ReferenceQuantization(
        relations=n,
        equal_odometry=float((length < EQUAL_TOLERANCE_M).mean()),
        on_grid=float(on_grid.mean()),
        rot_on_grid=float((gap < ROT_TOLERANCE_DEG).mean()),
        grid_m=grid_m,
        rot_grid_deg=rot_grid_deg,
        estimate_error_m=float(np.hypot(*(estimate[:, :2] - reference[:, :2]).T).mean()),
        floor_m=rounding_error(est_off, grid_m),
        estimate_noise_m=est_noise,
        reference_noise_m=ref_noise,
    )


def _covariance_split(
    est_off: np.ndarray, ref_off: np.ndarray, rounding_var: float
) -> tuple[tuple[float, float], tuple[float, float]]:
    """Per axis: if est = t + a and ref = t + b + rounding with t, a, b independent, then
    cov(est, ref) = var(t): what is left of each variance is the noise of each (std, m)."""
    if len(est_off) < 2:
        return (0.0, 0.0), (0.0, 0.0)
    est, ref = [], []
    for axis in (0, 1):
        c = np.cov(est_off[:, axis], ref_off[:, axis])
        est.append(math.sqrt(max(c[0, 0] - c[0, 1], 0.0)))
        ref.append(math.sqrt(max(c[1, 1] - c[0, 1] - rounding_var, 0.0)))
    return (est[0], est[1]), (ref[0], ref[1])
