"""The AMCL sensor model: the likelihood field (Thrun, Burgard, Fox, *Probabilistic Robotics*, 6.4).

Each beam endpoint scores ``z_hit * N(d; 0, sigma_hit) + z_rand / range_max`` where ``d`` is
the distance from the endpoint to the nearest occupied map cell
(``scipy.ndimage.distance_transform_edt``), capped at ``LIKELIHOOD_MAX_DIST_M``. Beams are
correlated, so the particle filter tempers the summed log-likelihood by ``BEAM_TEMPER``.

Shared by the particle filter (:mod:`sage_robot.nav.amcl`) and global localization
(:mod:`sage_robot.nav.amcl_global`); it imports neither.

Conventions: map frame, metres and radians; poses are (N, 3) arrays of (x, y, theta).
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from sage_robot.core.msgs import OccupancyGrid
from sage_robot.nav.costmap import OCCUPIED_MIN, GridGeometry

SIGMA_HIT_M = 0.2  # AMCL laser_sigma_hit
Z_HIT, Z_RAND = 0.5, 0.5  # AMCL laser_z_hit / laser_z_rand
LIKELIHOOD_MAX_DIST_M = 2.0  # AMCL laser_likelihood_max_dist
MAX_TRACE_STEPS = 400  # a traced ray gives up after this many steps and counts as clear (a ray
#   grazing a wall moves half a cell a step: 12 m at 0.05 m cells would take 480)
BEAM_TEMPER = 0.2  # beams are not independent: log-likelihoods are scaled by this


class LikelihoodField:
    """Distance (m) from every cell to the nearest occupied cell, capped, and a free-cell index."""

    def __init__(self, grid: OccupancyGrid) -> None:
        self.geom = GridGeometry.of(grid)
        occupied = grid.data >= OCCUPIED_MIN
        dist = ndimage.distance_transform_edt(~occupied) * grid.resolution
        self.dist = np.minimum(dist, LIKELIHOOD_MAX_DIST_M).astype(np.float32)
        self.known_free = np.asarray(grid.data == 0)
        self.free_cells = np.argwhere(self.known_free)
        if len(self.free_cells) == 0:
            raise ValueError("the map has no free cells to localize in")
        # Flat, padded copy: one border cell at the cap distance takes every point off the map.
        padded = np.pad(self.dist, 1, constant_values=LIKELIHOOD_MAX_DIST_M)
        self._width = padded.shape[1]
        self._rows, self._cols = padded.shape
        self._flat_dist = padded.ravel()
        self._log_tables: dict[tuple[float, float], np.ndarray] = {}

    def log_p_table(self, range_max: float, sigma: float = SIGMA_HIT_M) -> np.ndarray:
        """log(z_hit·N(d; 0, sigma) + z_rand/range_max) per (padded, flat) cell, cached.

        ``d`` is the distance less one cell: a return on a wall's surface lies on the border
        of an occupied and a free cell and lands in either by rounding, depending on which
        way the beam travels. Without the shift a place scored better than its mirror image
        (a beam from the other side rounds the other way), enough to pick the wrong one of
        two look-alike wings."""
        table = self._log_tables.get((range_max, sigma))
        if table is None:
            d = np.maximum(self._flat_dist - self.geom.resolution, 0.0)
            p = Z_HIT * np.exp(-0.5 * (d / sigma) ** 2) + Z_RAND / range_max
            table = np.log(p).astype(np.float32)
            self._log_tables[(range_max, sigma)] = table
        return table

    def flat_index(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Index into the padded flat tables; points off the map land on the border."""
        g = self.geom
        col = np.clip(((x - g.origin_x) / g.resolution).astype(np.int64) + 1, 0, self._cols - 1)
        row = np.clip(((y - g.origin_y) / g.resolution).astype(np.int64) + 1, 0, self._rows - 1)
        flat: np.ndarray = row * self._width + col
        return flat

    def on_free(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Whether each world point lies on a known-free cell (not a wall, not unknown)."""
        r, c = self.geom.to_cell(x, y)
        ok = self.geom.inside(r, c)
        out = np.zeros(np.shape(r), dtype=bool)
        out[ok] = self.known_free[r[ok], c[ok]]
        return out

    def crosses_wall(self, x0: float, y0: float, angles: np.ndarray, lengths: np.ndarray) -> np.ndarray:
        """Whether each ray from (x0, y0) meets an occupied cell within its length (m), by
        sphere tracing on the distance field: a ray advances by the distance to the nearest
        wall less one cell, at least half a cell, so it cannot step over a wall."""
        res = self.geom.resolution
        cos_a, sin_a = np.cos(angles), np.sin(angles)
        t = np.zeros(len(angles))
        hit = np.zeros(len(angles), dtype=bool)
        active = np.flatnonzero(lengths > 0)
        for _ in range(MAX_TRACE_STEPS):
            if active.size == 0:
                break
            d = self.distances(x0 + t[active] * cos_a[active], y0 + t[active] * sin_a[active])
            inside = d < 0.5 * res
            hit[active[inside]] = True
            t[active] += np.maximum(d - res, 0.5 * res)
            active = active[~inside & (t[active] < lengths[active])]
        return hit

    def distances(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Distances at world points; outside the map counts as far from everything."""
        r, c = self.geom.to_cell(x, y)
        ok = self.geom.inside(r, c)
        out = np.full(np.shape(r), LIKELIHOOD_MAX_DIST_M, dtype=np.float32)
        out[ok] = self.dist[r[ok], c[ok]]
        return out


def beam_log_likelihood(field: LikelihoodField, poses: np.ndarray, sensor: tuple[float, float, float],
                        angles: np.ndarray, ranges: np.ndarray, range_max: float,
                        sigma: float = SIGMA_HIT_M) -> np.ndarray:
    """Sum over beams of log(z_hit·N(d; 0, sigma) + z_rand/range_max) for each pose → (N,).
    ``sensor`` is the lidar's pose in base_link; pass only beams with a return."""
    sx, sy, st = sensor
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    ox = poses[:, 0] + c * sx - s * sy
    oy = poses[:, 1] + s * sx + c * sy
    # cos/sin of (theta_i + st + alpha_j) by the angle-sum rule: outer products, no trig per endpoint
    ct, stt = np.cos(poses[:, 2] + st).astype(np.float32), np.sin(poses[:, 2] + st).astype(np.float32)
    bx = (ranges * np.cos(angles)).astype(np.float32)  # beam endpoints in the sensor frame
    by = (ranges * np.sin(angles)).astype(np.float32)
    ex = ox.astype(np.float32)[:, None] + np.outer(ct, bx) - np.outer(stt, by)
    ey = oy.astype(np.float32)[:, None] + np.outer(stt, bx) + np.outer(ct, by)
    table = field.log_p_table(range_max, sigma)
    log_w: np.ndarray = table[field.flat_index(ex, ey)].sum(axis=1, dtype=np.float64)
    return log_w
