"""Scan-to-map refinement of a pose estimate (Gauss-Newton on a signed distance field).

The particle filter's mean carries the filter's own noise (motion noise, resampling; ~5 cm
on the shipped map even with perfect odometry). Once the cloud has gathered, placing the
whole scan on the map by least squares pins the pose to a centimetre or two, as the
scan matchers of Cartographer and Hector SLAM do. The filter itself is left alone: the
refined pose is what the robot reports and drives by.

Conventions: map frame, metres, radians. The field is the map's signed distance to the
nearest obstacle surface (positive in free space, negative inside walls), with the surface
half a cell from an occupied cell's centre, read bilinearly so it has a gradient.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from sage_robot.core.msgs import OccupancyGrid

OCCUPIED_MIN = 65  # map cell value (0..100) from which a cell is an obstacle
INLIER_M = 0.15  # returns further than this from the map (people, clutter) are left out (m)
MIN_INLIER_SHARE = 0.5  # refine only when this share of the returns lies on mapped walls
MIN_INLIERS = 30
ITERATIONS = 6
MAX_SHIFT_M = 0.15  # a refinement that moves the pose further than this is not trusted (m)
MAX_TURN_RAD = math.radians(3.0)  # nor one that turns it further than this
RETURN_SIGMA_M = 0.03  # spread of a return about the mapped surface (lidar noise, map cells) (m)
PRIOR_SIGMA_M = 0.05  # how far the filter's estimate is off, per axis (m) ...
PRIOR_SIGMA_RAD = math.radians(1.0)  # ... and in heading: where the scan says little (along a
#   bare corridor), the refined pose stays with the filter's
FIELD_CAP_M = 1.0  # the field is capped here; only distances under INLIER_M matter (m)


@dataclass(frozen=True)
class Refined:
    """A refined pose, how many returns it rests on and their RMS distance to the map (m)."""

    x: float
    y: float
    theta: float
    inliers: int
    rms_m: float


class SignedDistanceField:
    """The map's signed distance (m) to the nearest obstacle surface, and its gradient."""

    def __init__(self, grid: OccupancyGrid) -> None:
        if abs(grid.origin.theta) > 1e-6:
            raise ValueError("scan matching needs a map whose origin yaw is 0")
        res = grid.resolution
        occupied = np.asarray(grid.data) >= OCCUPIED_MIN
        outside = ndimage.distance_transform_edt(~occupied) * res  # free cells: to the nearest wall
        inside = ndimage.distance_transform_edt(occupied) * res  # wall cells: to the nearest free one
        sdf = np.where(occupied, -(inside - 0.5 * res), outside - 0.5 * res)
        self.sdf = np.clip(sdf, -FIELD_CAP_M, FIELD_CAP_M).astype(np.float64)
        gy, gx = np.gradient(self.sdf, res)
        self.gx, self.gy = gx, gy
        self.origin = (grid.origin.x, grid.origin.y)
        self.res = res

    def sample(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Signed distance and its gradient (d/dx, d/dy) at world points, bilinear; off the map
        reads as far from everything (no gradient)."""
        # cell centres are at origin + (i + 0.5) * res: fractional index of the point
        col = (x - self.origin[0]) / self.res - 0.5
        row = (y - self.origin[1]) / self.res - 0.5
        coords = np.vstack([row, col])
        kw = {"order": 1, "mode": "constant", "cval": 0.0}
        d = ndimage.map_coordinates(self.sdf, coords, **kw)
        rows, cols = self.sdf.shape
        off = (row < 0) | (col < 0) | (row > rows - 1) | (col > cols - 1)
        d[off] = FIELD_CAP_M
        gx = ndimage.map_coordinates(self.gx, coords, **kw)
        return d, gx, ndimage.map_coordinates(self.gy, coords, **kw)


def refine(field: SignedDistanceField, pose: tuple[float, float, float], sensor: tuple[float, float, float],
           angles: np.ndarray, ranges: np.ndarray, range_max: float) -> Refined | None:
    """Least-squares placement of the scan on the map, starting at ``pose`` (base_link in the
    map frame; ``sensor`` is the lidar in base_link). ``None`` when too few returns lie on
    mapped walls or the answer jumps further than the estimate can be off."""
    ok = np.isfinite(ranges) & (ranges > 0) & (ranges < range_max)
    if ok.sum() < MIN_INLIERS:
        return None
    sx, sy, st = sensor
    bx = ranges[ok] * np.cos(angles[ok] + st) + sx  # returns in base_link
    by = ranges[ok] * np.sin(angles[ok] + st) + sy
    x, y, th = pose
    inl = np.zeros(len(bx), dtype=bool)
    d = np.zeros(len(bx))
    prior = np.diag([(RETURN_SIGMA_M / PRIOR_SIGMA_M) ** 2] * 2 + [(RETURN_SIGMA_M / PRIOR_SIGMA_RAD) ** 2])
    p0 = np.array(pose, dtype=np.float64)
    for _ in range(ITERATIONS):
        c, s = math.cos(th), math.sin(th)
        ex, ey = x + c * bx - s * by, y + s * bx + c * by
        d, gx, gy = field.sample(ex, ey)
        inl = np.abs(d) < INLIER_M
        if inl.sum() < max(MIN_INLIERS, MIN_INLIER_SHARE * len(bx)):
            return None
        # d(endpoint)/d(theta) = (-(ey - y), ex - x)
        j = np.column_stack([gx[inl], gy[inl], gx[inl] * -(ey[inl] - y) + gy[inl] * (ex[inl] - x)])
        # minimise sum(d^2) + (p - p0)' prior (p - p0): Gauss-Newton on both
        dev = np.array([x, y, th]) - p0
        step = np.linalg.solve(j.T @ j + prior, -(j.T @ d[inl] + prior @ dev))
        x, y, th = x + float(step[0]), y + float(step[1]), th + float(step[2])
        if abs(step[0]) + abs(step[1]) < 1e-4 and abs(step[2]) < 1e-4:
            break
    if math.hypot(x - pose[0], y - pose[1]) > MAX_SHIFT_M or abs(th - pose[2]) > MAX_TURN_RAD:
        return None
    return Refined(x, y, math.atan2(math.sin(th), math.cos(th)), int(inl.sum()),
                   float(np.sqrt(np.mean(d[inl] ** 2))))
