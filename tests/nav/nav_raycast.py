"""A small lidar model for navigation tests: march all beams at once through the grid and
past circles (people). Map frame, metres, radians."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from sage_robot.core.msgs import OccupancyGrid

LIDAR_BEAMS = 360
RANGE_MAX_M = 12.0
RANGE_MIN_M = 0.15


def cast(grid: OccupancyGrid, origin: tuple[float, float, float], angles: np.ndarray,
         people: Sequence[tuple[float, float, float]] = (), range_max: float = RANGE_MAX_M) -> np.ndarray:
    """Ranges (m, inf = no return) of beams at ``angles`` (sensor frame) from ``origin``
    (x, y, yaw of the sensor). ``people`` are circles (x, y, radius)."""
    ox, oy, oyaw = origin
    a = angles + oyaw
    step = grid.resolution * 0.5
    t = np.arange(1, int(range_max / step) + 1) * step
    px = ox + np.cos(a)[:, None] * t[None, :]
    py = oy + np.sin(a)[:, None] * t[None, :]
    col = np.floor((px - grid.origin.x) / grid.resolution).astype(np.int64)
    row = np.floor((py - grid.origin.y) / grid.resolution).astype(np.int64)
    inside = (row >= 0) & (row < grid.height) & (col >= 0) & (col < grid.width)
    hit = np.zeros(px.shape, dtype=bool)
    hit[inside] = grid.data[row[inside], col[inside]] >= 50
    first = np.where(hit.any(axis=1), t[np.argmax(hit, axis=1)], np.inf)
    dx, dy = np.cos(a), np.sin(a)
    for cx, cy, r in people:  # exact ray-circle intersection
        fx, fy = ox - cx, oy - cy
        b = fx * dx + fy * dy
        c = fx * fx + fy * fy - r * r
        disc = b * b - c
        ok = disc >= 0
        d = np.where(ok, -b - np.sqrt(np.maximum(disc, 0.0)), np.inf)
        d[d < 0] = np.inf
        first = np.minimum(first, d)
    first[first > range_max] = np.inf
    return first.astype(np.float32)


def beam_angles(n: int = LIDAR_BEAMS) -> np.ndarray:
    return -math.pi + (2 * math.pi / n) * np.arange(n)
