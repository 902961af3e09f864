"""Scores that can see accuracy on a rounded reference: the distance to the rounding cell.

A reference made by a grid search around the odometry (the MIT CSAIL relations of Kümmerle et
al. 2009, see :mod:`refcheck`) stands for every true relation that the search would have
rounded to it. Its translation was rounded on a square ``step_m`` grid whose axes are fixed in
the map frame: with ``φ`` the heading of the relation's first pose in the grid's frame,
``R(φ)(δ* − δ_odo)`` is a grid vector. So the **cell** of a reference relation δ* is the set
of true relations δ with ``R(φ)(δ − δ*)`` in the box ``[−step/2, step/2]²`` (a square turned
by −φ in the first pose's frame), and a rotation within ``±rot_step/2`` of δ*'s.

:func:`cell_errors` measures, per relation, how far an estimate δ is from that cell: the
Euclidean distance (m) from ``R(φ)(δ − δ*)`` to the box (0 inside), and how far (rad) its
rotation is beyond the half step. A perfect estimator scores 0 and 100 % inside, where
Kümmerle's mean error of the same estimator is the rounding (1.6–1.9 cm on MIT CSAIL).

The grid's heading in our map frame is not known in advance (the reference's world frame
turns slowly against ours as the two headings drift apart): :func:`grid_heading` measures it
from the reference's own offsets from the odometry (those whose grid vector has one direction
modulo 90°: 1, √2, 2, 2√2, 3 … cells) and smooths it over time. Frames: translations in the
first pose's frame (m), rotations and headings in rad; the map frame's heading of a relation's
first pose is the estimate's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sage_robot.core.geometry import wrap_angles

GRID_STEP_M = 0.05  # the MIT CSAIL reference's translation grid
ROT_STEP_RAD = math.radians(0.25)  # ... and its rotation grid
QUARTER_TURN = math.pi / 2  # a square grid looks the same every 90°
AXIS_CELLS2 = (1, 4, 9, 16)  # squared lengths (cells²) of grid vectors along an axis...
DIAGONAL_CELLS2 = (2, 8, 18)  # ...and along a diagonal: one direction modulo 90°
CELLS2_TOLERANCE = 0.02  # |offset|²/step² this close to one of those: on the grid
HEADING_WINDOW = 41  # grid-heading measurements averaged around each relation (nearest in time)
MAX_HEADING_SPREAD_RAD = math.radians(10.0)  # a measurement farther than this from its
# neighbours' mean (e.g. our heading wrong for a moment) is left out of the average


@dataclass(frozen=True)
class CellScore:
    """Rounding-cell scores of a set of relations (means over them)."""

    relations: int
    trans_mean_m: float  # distance of the estimate's translation to its cell (0 inside)
    rot_mean_deg: float  # rotation error beyond the half step (0 inside)
    inside_trans: float  # share of relations whose translation is inside the cell
    inside_rot: float  # share whose rotation is inside
    inside: float  # share with both inside
    heading_measurements: int = 0  # relations the grid heading was measured on
    heading_range_deg: tuple[float, float] = (0.0, 0.0)  # grid heading in our map frame, min/max

    def as_dict(self) -> dict[str, float | int | list[float]]:
        return {
            "cell_relations": self.relations,
            "cell_trans_mean_m": round(self.trans_mean_m, 5),
            "cell_rot_mean_deg": round(self.rot_mean_deg, 4),
            "cell_inside_trans": round(self.inside_trans, 3),
            "cell_inside_rot": round(self.inside_rot, 3),
            "cell_inside": round(self.inside, 3),
            "cell_grid_heading_deg": [round(v, 2) for v in self.heading_range_deg],
            "cell_grid_heading_measurements": self.heading_measurements,
        }


def cell_errors(
    reference: np.ndarray,
    estimate: np.ndarray,
    grid_frame: np.ndarray,
    step_m: float = GRID_STEP_M,
    rot_step_rad: float = ROT_STEP_RAD,
) -> tuple[np.ndarray, np.ndarray]:
    """Per relation: (distance (m) of the estimate's translation to the reference's cell,
    rotation error beyond the half step (rad)), both 0 inside the cell.

    ``reference`` and ``estimate`` are (N, 3) relative poses (dx, dy m in the first pose's
    frame; dθ rad); ``grid_frame`` (N,) is φ, the heading (rad) of each first pose in the
    frame of the grid the reference was rounded on.
    """
    reference = np.asarray(reference, dtype=np.float64).reshape(-1, 3)
    estimate = np.asarray(estimate, dtype=np.float64).reshape(-1, 3)
    phi = np.asarray(grid_frame, dtype=np.float64).reshape(-1)
    d = estimate[:, :2] - reference[:, :2]
    c, s = np.cos(phi), np.sin(phi)
    u = np.column_stack((c * d[:, 0] - s * d[:, 1], s * d[:, 0] + c * d[:, 1]))
    outside = np.maximum(np.abs(u) - step_m / 2, 0.0)
    trans = np.hypot(outside[:, 0], outside[:, 1])
    rot = np.maximum(np.abs(wrap_angles(estimate[:, 2] - reference[:, 2])) - rot_step_rad / 2, 0.0)
    return trans, rot


def offset_directions(
    reference: np.ndarray, odometry: np.ndarray, map_heading: np.ndarray, step_m: float = GRID_STEP_M
) -> np.ndarray:
    """Per relation, the grid's heading in the map frame (rad, in [−45°, 45°)) that puts the
    reference's offset from the odometry on the grid; NaN where the offset is zero or its
    length has more than one direction modulo 90° (√5 cells: 26.6° or 63.4°).

    ``map_heading`` (N,): heading (rad) of each relation's first pose in the map frame.
    """
    reference = np.asarray(reference, dtype=np.float64).reshape(-1, 3)
    odometry = np.asarray(odometry, dtype=np.float64).reshape(-1, 3)
    off = reference[:, :2] - odometry[:, :2]
    cells2 = (off[:, 0] ** 2 + off[:, 1] ** 2) / step_m**2
    along = np.full(len(off), np.nan)
    for value in AXIS_CELLS2:
        along[np.abs(cells2 - value) < CELLS2_TOLERANCE] = 0.0
    for value in DIAGONAL_CELLS2:
        along[np.abs(cells2 - value) < CELLS2_TOLERANCE] = math.pi / 4
    angle = np.arctan2(off[:, 1], off[:, 0]) + np.asarray(map_heading, dtype=np.float64) - along
    out: np.ndarray = (angle + QUARTER_TURN / 2) % QUARTER_TURN - QUARTER_TURN / 2
    return out


def _quarter_mean(angles: np.ndarray) -> float:
    """Mean of angles that are only defined modulo 90° (rad, in [−45°, 45°))."""
    z = np.exp(4j * angles).mean()
    return float(np.angle(z) / 4)


def grid_heading(stamps: np.ndarray, directions: np.ndarray, window: int = HEADING_WINDOW) -> np.ndarray:
    """The grid's heading in the map frame at each of ``stamps`` (rad): the mean (modulo 90°)
    of the ``window`` measurements nearest in time, ``directions`` being NaN where a relation
    measured nothing. All zero when nothing was measured."""
    stamps = np.asarray(stamps, dtype=np.float64)
    directions = np.asarray(directions, dtype=np.float64)
    ok = np.isfinite(directions)
    if not ok.any():
        return np.zeros(len(stamps))
    t, a = stamps[ok], directions[ok]
    order = np.argsort(t)
    t, a = t[order], a[order]
    out = np.empty(len(stamps))
    for k, when in enumerate(stamps):
        near = a[np.argsort(np.abs(t - when), kind="stable")[:window]]
        mean = _quarter_mean(near)
        spread = np.abs((near - mean + QUARTER_TURN / 2) % QUARTER_TURN - QUARTER_TURN / 2)
        kept = near[spread <= MAX_HEADING_SPREAD_RAD]
        out[k] = _quarter_mean(kept) if len(kept) else mean
    return out


def cell_score(
    reference: np.ndarray,
    odometry: np.ndarray,
    estimate: np.ndarray,
    map_heading: np.ndarray,
    stamps: np.ndarray,
    step_m: float = GRID_STEP_M,
    rot_step_rad: float = ROT_STEP_RAD,
) -> CellScore:
    """Rounding-cell scores of ``estimate`` against a ``reference`` rounded around ``odometry``.

    All three are (N, 3) relative poses of the same relations (dx, dy m in the first pose's
    frame; dθ rad); ``map_heading`` (N,) is the estimate's heading of each first pose in the
    map frame (rad) and ``stamps`` (N,) its time (s), to follow the grid's slow turn.
    """
    reference = np.asarray(reference, dtype=np.float64).reshape(-1, 3)
    n = len(reference)
    if n == 0:
        return CellScore(0, 0.0, 0.0, 0.0, 0.0, 0.0)
    directions = offset_directions(reference, odometry, map_heading, step_m)
    psi = grid_heading(stamps, directions)
    phi = np.asarray(map_heading, dtype=np.float64) - psi
    trans, rot = cell_errors(reference, estimate, phi, step_m, rot_step_rad)
    inside_t, inside_r = trans == 0.0, rot == 0.0
    return CellScore(
        relations=n,
        trans_mean_m=float(trans.mean()),
        rot_mean_deg=math.degrees(float(rot.mean())),
        inside_trans=float(inside_t.mean()),
        inside_rot=float(inside_r.mean()),
        inside=float((inside_t & inside_r).mean()),
        heading_measurements=int(np.isfinite(directions).sum()),
        heading_range_deg=(math.degrees(float(psi.min())), math.degrees(float(psi.max()))),
    )
