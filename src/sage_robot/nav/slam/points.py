"""Scan geometry: ranges → points, voxel filtering, point normals. Pure numpy (+ scipy KD-tree).

Frames: a scan's points are given in the robot frame (x forward, y left, m); a pose
(x, y, theta) maps them to the map frame (REP 103).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

Pose = tuple[float, float, float]

NORMAL_NEIGHBOURS = 8  # points used to fit each normal
NORMAL_MAX_SPREAD_M = 0.3  # neighbours further than this do not shape a normal


@dataclass(frozen=True)
class Scan:
    """A laser scan reduced to what SLAM needs.

    ``ranges`` (m) and ``angles`` (rad, laser frame); ``laser`` is the laser's pose in the robot
    frame. Readings outside ``(range_min, range_max)`` are no returns.
    """

    ranges: np.ndarray
    angles: np.ndarray
    range_min: float
    range_max: float
    laser: Pose = (0.0, 0.0, 0.0)

    def hits(self, max_range: float) -> np.ndarray:
        """Mask of the readings that hit something closer than ``max_range`` (m)."""
        r = self.ranges
        mask: np.ndarray = np.isfinite(r) & (r > self.range_min) & (r < min(self.range_max, max_range))
        return mask

    def points(self, max_range: float) -> np.ndarray:
        """(N, 2) end points of the hits, in the robot frame (m)."""
        mask = self.hits(max_range)
        r, a = self.ranges[mask].astype(np.float64), self.angles[mask]
        lx, ly, lt = self.laser
        return np.column_stack((lx + r * np.cos(a + lt), ly + r * np.sin(a + lt)))


def transform(pose: Pose | np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Points (N, 2) from the pose's frame to its parent frame."""
    x, y, t = float(pose[0]), float(pose[1]), float(pose[2])
    c, s = math.cos(t), math.sin(t)
    out = np.empty_like(pts)
    out[:, 0] = c * pts[:, 0] - s * pts[:, 1] + x
    out[:, 1] = s * pts[:, 0] + c * pts[:, 1] + y
    return out


def voxel_filter(pts: np.ndarray, size: float) -> np.ndarray:
    """One point per ``size`` (m) square cell: the mean of the points in it."""
    if len(pts) == 0:
        return pts
    keys = np.floor(pts / size).astype(np.int64)
    keys -= keys.min(axis=0)
    flat = keys[:, 0] * (int(keys[:, 1].max()) + 1) + keys[:, 1]
    uniq, inverse, counts = np.unique(flat, return_inverse=True, return_counts=True)
    sums = np.zeros((len(uniq), 2))
    np.add.at(sums, inverse, pts)
    centroids: np.ndarray = sums / counts[:, None]
    return centroids


def voxel_indices(pts: np.ndarray, size: float) -> np.ndarray:
    """Indices of one point per ``size`` (m) square cell (the first one in it)."""
    if len(pts) == 0:
        return np.zeros(0, dtype=np.int64)
    keys = np.floor(pts / size).astype(np.int64)
    keys -= keys.min(axis=0)
    flat = keys[:, 0] * (int(keys[:, 1].max()) + 1) + keys[:, 1]
    return np.sort(np.unique(flat, return_index=True)[1])


def rotate(theta: float, vecs: np.ndarray) -> np.ndarray:
    """Directions (N, 2) turned by ``theta`` (rad)."""
    c, s = math.cos(theta), math.sin(theta)
    return np.column_stack((c * vecs[:, 0] - s * vecs[:, 1], s * vecs[:, 0] + c * vecs[:, 1]))


def normals(pts: np.ndarray, tree: object) -> np.ndarray:
    """Unit normals (N, 2) by principal axes of each point's neighbours (``tree``: a cKDTree
    of ``pts``). A point without enough close neighbours gets a zero normal."""
    k = min(NORMAL_NEIGHBOURS, len(pts))
    if k < 3:
        return np.zeros_like(pts)
    dist, idx = tree.query(pts, k=k, distance_upper_bound=NORMAL_MAX_SPREAD_M)  # type: ignore[attr-defined]
    valid = np.isfinite(dist)
    idx = np.where(valid, idx, np.arange(len(pts))[:, None])
    nb = pts[idx]  # (N, k, 2)
    w = valid.astype(np.float64)
    cnt = np.maximum(w.sum(axis=1), 1.0)
    mean = (nb * w[:, :, None]).sum(axis=1) / cnt[:, None]
    d = (nb - mean[:, None, :]) * w[:, :, None]
    sxx = (d[:, :, 0] ** 2).sum(axis=1)
    syy = (d[:, :, 1] ** 2).sum(axis=1)
    sxy = (d[:, :, 0] * d[:, :, 1]).sum(axis=1)
    # Smallest-eigenvalue direction of [[sxx, sxy], [sxy, syy]]: the line's normal.
    angle = 0.5 * np.arctan2(2.0 * sxy, sxx - syy) + np.pi / 2.0
    out = np.column_stack((np.cos(angle), np.sin(angle)))
    out[cnt < 3] = 0.0
    return out
