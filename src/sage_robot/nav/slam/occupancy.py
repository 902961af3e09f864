"""Log-odds occupancy grid built from scans at known poses, with vectorised ray casting.

Cells are ``resolution`` (m) squares; ``logodds[row, col]`` with row = y, column = x and the
grid's lower-left corner at ``origin`` (m, map frame), as :class:`OccupancyGrid`. Every beam
adds ``L_FREE`` to the cells it crosses and ``L_OCC`` to the cell it ends in; a beam with no
return clears up to the scan's range_max (at most ``max_range``) without marking an end. The
grid grows in ``GROW_M`` steps as scans reach beyond it.
"""

from __future__ import annotations

import math

import numpy as np

from sage_robot.core.msgs import OccupancyGrid, Pose2D
from sage_robot.nav.slam.points import Pose, Scan

L_OCC = 0.85  # log-odds added by a hit (p = 0.7)
L_FREE = -0.4  # log-odds added by a pass (p = 0.4)
L_CLAMP = 6.0  # |log-odds| bound
OCC_LOGODDS = 0.62  # above this (p > 0.65): occupied (100)
FREE_LOGODDS = -1.1  # below this (p < 0.25): free (0)
GROW_M = 10.0  # the grid grows by this much (m) on a side when a scan leaves it
RAY_STEP_CELLS = 0.5  # samples per cell along a beam
# A beam without a return may be open space, or a return the lidar lost: too close to read
# (under range_min: a wall the robot brushes past), a dropout, a black or glass surface. Only
# runs of at least OPEN_RUN_BEAMS such beams, whose neighbours on both sides returned from at
# least OPEN_BORDER_M, clear as open space; the others clear nothing.
OPEN_RUN_BEAMS = 3
OPEN_BORDER_M = 0.5
CLEAR_SIGMAS = 2.0  # a returned beam clears only up to this many range-noise sigmas short of its end


def open_space(ranges: np.ndarray, no_return: np.ndarray) -> np.ndarray:
    """Mask of the ``no_return`` beams that look into open space: in runs of at least
    ``OPEN_RUN_BEAMS``, between returns (or the scan's ends) at least ``OPEN_BORDER_M`` away."""
    n = len(no_return)
    if n == 0 or not no_return.any():
        return np.zeros(n, dtype=bool)
    edges = np.diff(np.concatenate(([0], no_return.astype(np.int8), [0])))
    starts, stops = np.nonzero(edges == 1)[0], np.nonzero(edges == -1)[0]  # runs [start, stop)
    far = np.concatenate(([True], np.nan_to_num(ranges, nan=0.0) >= OPEN_BORDER_M, [True]))
    ok = (stops - starts >= OPEN_RUN_BEAMS) & far[starts] & far[stops + 1]
    out = np.zeros(n, dtype=bool)
    for a, b in zip(starts[ok], stops[ok], strict=True):
        out[a:b] = True
    return out


class OccupancyMapper:
    def __init__(
        self, resolution: float = 0.05, max_range: float = 30.0, range_noise_fraction: float = 0.0
    ) -> None:
        if resolution <= 0:
            raise ValueError("resolution must be > 0 m")
        self.resolution = resolution
        self.max_range = max_range
        # The lidar's range noise as a fraction of the range (1 sigma): a return may lie that far
        # beyond a far wall, so its beam leaves the wall's band uncleared.
        self.range_noise_fraction = range_noise_fraction
        self.origin = np.zeros(2)
        self.logodds = np.zeros((0, 0), dtype=np.float32)
        self.seen = np.zeros((0, 0), dtype=bool)

    def clear(self) -> None:
        self.logodds = np.zeros((0, 0), dtype=np.float32)
        self.seen = np.zeros((0, 0), dtype=bool)

    def _ensure(self, lo: np.ndarray, hi: np.ndarray) -> None:
        res = self.resolution
        h, w = self.logodds.shape
        if h and w:
            top = self.origin + np.array([w, h]) * res
            if (lo >= self.origin).all() and (hi < top).all():
                return
            new_lo = np.minimum(self.origin, np.floor((lo - GROW_M) / res) * res)
            new_hi = np.maximum(top, hi + GROW_M)
        else:
            new_lo, new_hi = np.floor((lo - GROW_M) / res) * res, hi + GROW_M
        shape = (math.ceil((new_hi[1] - new_lo[1]) / res), math.ceil((new_hi[0] - new_lo[0]) / res))
        grid = np.zeros(shape, dtype=np.float32)
        seen = np.zeros(shape, dtype=bool)
        if h and w:
            oy, ox = np.round((self.origin - new_lo)[::-1] / res).astype(int)
            grid[oy : oy + h, ox : ox + w] = self.logodds
            seen[oy : oy + h, ox : ox + w] = self.seen
        self.origin, self.logodds, self.seen = new_lo, grid, seen

    def integrate(self, pose: Pose, scan: Scan) -> None:
        """Add one scan taken at ``pose`` (robot pose in the map frame)."""
        self.integrate_many([pose], [scan])

    def integrate_many(self, poses: list[Pose], scans: list[Scan]) -> None:
        if not scans:
            return
        starts, ends, hit = [], [], []
        for pose, scan in zip(poses, scans, strict=False):
            lx, ly, lt = scan.laser
            c, s = math.cos(pose[2]), math.sin(pose[2])
            ox, oy = pose[0] + c * lx - s * ly, pose[1] + s * lx + c * ly
            r = np.asarray(scan.ranges, dtype=np.float64)
            valid = np.isfinite(r) & (r > scan.range_min)
            returned = valid & (r < min(scan.range_max, self.max_range))
            # +inf or at range_max: nothing came back (REP 117: -inf is "too close", NaN an error)
            no_return = np.isposinf(r) | (np.isfinite(r) & (r >= scan.range_max))
            use = returned | open_space(r, no_return)
            length = np.where(returned, r, min(scan.range_max, self.max_range))[use]
            a = scan.angles[use] + lt + pose[2]
            starts.append(np.repeat([[ox, oy]], len(a), axis=0))
            ends.append(np.column_stack((ox + length * np.cos(a), oy + length * np.sin(a))))
            hit.append(returned[use])
        p0, p1, h = np.concatenate(starts), np.concatenate(ends), np.concatenate(hit)
        if len(p0) == 0:  # not one beam to draw (all too close, errors or lost)
            return
        self._ensure(np.minimum(p0.min(axis=0), p1.min(axis=0)), np.maximum(p0.max(axis=0), p1.max(axis=0)))
        self._cast(p0, p1, h)

    def _cast(self, p0: np.ndarray, p1: np.ndarray, hit: np.ndarray) -> None:
        res = self.resolution
        height, width = self.logodds.shape
        seg = p1 - p0
        length = np.hypot(seg[:, 0], seg[:, 1])
        step = res * RAY_STEP_CELLS
        counts = np.maximum((length / step).astype(np.int64), 1)
        total = int(counts.sum())
        beam = np.repeat(np.arange(len(counts)), counts)
        first = np.cumsum(counts) - counts
        k = np.arange(total) - np.repeat(first, counts)
        t = (k * step / np.maximum(length, 1e-9)[beam])[:, None]
        pts = p0[beam] + t * seg[beam]
        cells = np.floor((pts - self.origin) / res).astype(np.int64)
        flat = cells[:, 1] * width + cells[:, 0]
        end_cells = np.floor((p1 - self.origin) / res).astype(np.int64)
        end_flat = end_cells[:, 1] * width + end_cells[:, 0]
        # A beam's own end cell is not cleared by it; samples along a beam are in order, so
        # one update per beam and cell = drop a sample in the same cell as the one before.
        keep = flat != end_flat[beam]
        if self.range_noise_fraction > 0:
            clear_to = np.where(hit, length * (1.0 - CLEAR_SIGMAS * self.range_noise_fraction), length)
            keep &= k * step < clear_to[beam]
        keep[1:] &= (flat[1:] != flat[:-1]) | (beam[1:] != beam[:-1])
        key = flat[keep]
        free = np.bincount(key, minlength=height * width)
        occ = np.bincount(end_flat[hit], minlength=height * width)
        upd = (L_FREE * free + L_OCC * occ).reshape(height, width).astype(np.float32)
        np.clip(self.logodds + upd, -L_CLAMP, L_CLAMP, out=self.logodds)
        self.seen |= (free + occ).reshape(height, width) > 0

    def rebuild(self, poses: list[Pose], scans: list[Scan], batch: int = 64) -> None:
        """Start again from these poses (e.g. after the pose graph was optimised)."""
        self.clear()
        for k in range(0, len(scans), batch):
            self.integrate_many(poses[k : k + batch], scans[k : k + batch])

    def to_grid(self, stamp: float = 0.0, frame_id: str = "map", crop: bool = True) -> OccupancyGrid:
        """-1 unknown, 0 free, 100 occupied, in between the probability in percent."""
        data = np.full(self.logodds.shape, -1, dtype=np.int8)
        prob = 1.0 - 1.0 / (1.0 + np.exp(self.logodds))
        data[self.seen] = np.rint(100 * prob[self.seen]).astype(np.int8)
        data[self.seen & (self.logodds > OCC_LOGODDS)] = 100
        data[self.seen & (self.logodds < FREE_LOGODDS)] = 0
        origin = self.origin.copy()
        if crop and self.seen.any():
            rows, cols = np.nonzero(self.seen)
            r0, r1, c0, c1 = rows.min(), rows.max() + 1, cols.min(), cols.max() + 1
            data = data[r0:r1, c0:c1]
            origin = origin + np.array([c0, r0]) * self.resolution
        return OccupancyGrid(
            stamp,
            frame_id,
            self.resolution,
            Pose2D(float(origin[0]), float(origin[1]), 0.0),
            np.ascontiguousarray(data),
        )
