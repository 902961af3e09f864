"""Small things in front of the background in a scan: people's legs, which SLAM must not match.

In a long bare corridor a person's two legs can be the only feature along the corridor, and
a slowly walking person then drags the matched pose along with them. A *small foreground
object* is a run of consecutive returns no wider than ``max_extent_m`` whose neighbouring
beams on both sides reach at least ``DEPTH_GAP_M`` farther (or return nothing): a leg, a
chair leg, a thin post. Walls, door frames and furniture are wider or continue into their
neighbours, and stay. Pure numpy; ranges (m) in beam order, ``inf``/out of range = no return.

:func:`supported` drops points of a merged local map that only one keyframe saw in their cell
(what moved between keyframes).
"""

from __future__ import annotations

import numpy as np

DEPTH_GAP_M = 0.1  # the background beside a foreground object is at least this much farther
BREAK_M = 0.1  # consecutive returns farther apart than this (plus the beam spread) split a run
BREAK_BEAMS = 3.0  # ...plus this many beam spacings at the range


def small_foreground(
    ranges: np.ndarray, angles: np.ndarray, hits: np.ndarray, max_extent_m: float
) -> np.ndarray:
    """Mask (like ``hits``) of the returns that belong to small foreground objects."""
    out = np.zeros(len(ranges), dtype=bool)
    idx = np.nonzero(hits)[0]
    if len(idx) < 2 or max_extent_m <= 0:
        return out
    r = ranges[idx].astype(np.float64)
    a = angles[idx]
    xy = np.column_stack((r * np.cos(a), r * np.sin(a)))
    step = np.hypot(*np.diff(xy, axis=0).T)
    spacing = np.abs(np.diff(a)) * np.minimum(r[:-1], r[1:])
    brk = (np.diff(idx) > 1) | (step > BREAK_M + BREAK_BEAMS * spacing)
    run = np.concatenate(([0], np.cumsum(brk)))
    starts = np.concatenate(([0], np.nonzero(brk)[0] + 1))
    ends = np.concatenate((np.nonzero(brk)[0], [len(idx) - 1]))
    extent = np.hypot(*(xy[ends] - xy[starts]).T)
    full = np.where(hits, ranges, np.inf).astype(np.float64)
    n = len(ranges)
    before = full[(idx[starts] - 1) % n]
    after = full[(idx[ends] + 1) % n]
    small = (
        (extent <= max_extent_m)
        & (before > r[starts] + DEPTH_GAP_M)
        & (after > r[ends] + DEPTH_GAP_M)
    )
    out[idx] = small[run]
    return out


def supported(pts: np.ndarray, owner: np.ndarray, cell_m: float, need: int) -> np.ndarray:
    """Mask of the points whose ``cell_m`` cell holds points of at least ``need`` owners (e.g.
    keyframes: a walking person's legs are somewhere else in every keyframe)."""
    if len(pts) == 0:
        return np.zeros(0, dtype=bool)
    keys = np.floor(pts / cell_m).astype(np.int64)
    keys -= keys.min(axis=0)
    flat = keys[:, 0] * (int(keys[:, 1].max()) + 1) + keys[:, 1]
    cells, inverse = np.unique(flat, return_inverse=True)
    pairs = np.unique(inverse * (int(owner.max()) + 1) + owner)
    owners_per_cell = np.bincount(pairs // (int(owner.max()) + 1), minlength=len(cells))
    mask: np.ndarray = owners_per_cell[inverse] >= need
    return mask
