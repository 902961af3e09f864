"""How well a SLAM map agrees with the true map it was made in (simulation ground truth).

- *Wall distance*: for every occupied cell of the SLAM map, the distance (m) from its centre
  to the nearest true wall (the square of an occupied cell of the true map; 0 inside one).
  Reported as the mean (each distance capped at ``FAR_M``, so one stray cell cannot dominate),
  the median and the fraction within ``tol_m`` (precision).
- *Walls found*: of the true wall cells the robot's lidar actually hit (``seen``: a mask on
  the true grid, from the simulator's true ranges), the fraction with an occupied SLAM cell
  within ``tol_m`` (recall).

Pure numpy/scipy; grids are ``OccupancyGrid`` messages (row = y, column = x, 100 = occupied),
their origins unrotated.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import distance_transform_edt

from sage_robot.core.msgs import OccupancyGrid

OCCUPIED_MIN = 65  # a cell at least this occupied is a wall
FAR_M = 1.0  # a mapped wall cell farther than this from any true wall counts as this far
MATCH_TOL_M = 0.1


@dataclass(frozen=True)
class MapScore:
    wall_distance_mean_m: float
    wall_distance_median_m: float
    precision: float  # mapped wall cells within tol of a true wall
    walls_found: float  # seen true wall cells with a mapped wall within tol
    mapped_cells: int
    seen_cells: int

    def as_dict(self) -> dict[str, float | int]:
        return {
            "wall_distance_mean_m": round(self.wall_distance_mean_m, 4),
            "wall_distance_median_m": round(self.wall_distance_median_m, 4),
            "occupied_precision": round(self.precision, 4),
            "walls_found": round(self.walls_found, 4),
            "mapped_wall_cells": self.mapped_cells,
            "seen_wall_cells": self.seen_cells,
        }


def _cell_of(grid: OccupancyGrid, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Continuous (column, row) coordinates of map points in ``grid`` (cells)."""
    return (x - grid.origin.x) / grid.resolution, (y - grid.origin.y) / grid.resolution


def cell_centres(grid: OccupancyGrid, mask: np.ndarray) -> np.ndarray:
    """(N, 2) map-frame centres (m) of the cells of ``grid`` where ``mask`` is set."""
    rows, cols = np.nonzero(mask)
    return np.column_stack(
        (grid.origin.x + (cols + 0.5) * grid.resolution, grid.origin.y + (rows + 0.5) * grid.resolution)
    )


def wall_distance(truth: OccupancyGrid, pts: np.ndarray) -> np.ndarray:
    """Distance (m) from map points to the nearest true wall cell's square; points more than
    ``FAR_M`` off the true grid are inf (a noisy return just behind a wall drawn on the map's
    edge is as near that wall as one just in front of it)."""
    wall = truth.data >= OCCUPIED_MIN
    if not wall.any() or len(pts) == 0:
        return np.full(len(pts), np.inf)
    pad = int(np.ceil(FAR_M / truth.resolution))
    wall = np.pad(wall, pad)
    _, (feat_r, feat_c) = distance_transform_edt(~wall, return_indices=True)
    gx, gy = _cell_of(truth, pts[:, 0], pts[:, 1])
    gx, gy = gx + pad, gy + pad
    col, row = np.floor(gx).astype(np.int64), np.floor(gy).astype(np.int64)
    h, w = wall.shape
    inside = (row >= 0) & (row < h) & (col >= 0) & (col < w)
    out = np.full(len(pts), np.inf)
    r, c = row[inside], col[inside]
    ex = np.maximum(np.abs(gx[inside] - (feat_c[r, c] + 0.5)) - 0.5, 0.0)
    ey = np.maximum(np.abs(gy[inside] - (feat_r[r, c] + 0.5)) - 0.5, 0.0)
    out[inside] = np.hypot(ex, ey) * truth.resolution
    return out


def walls_found(truth: OccupancyGrid, seen: np.ndarray, mapped: OccupancyGrid, tol_m: float) -> float:
    """Fraction of the seen true wall cells with a mapped wall cell centre within ``tol_m``."""
    pts = cell_centres(truth, seen & (truth.data >= OCCUPIED_MIN))
    occ = mapped.data >= OCCUPIED_MIN
    if len(pts) == 0:
        return 0.0
    if not occ.any():
        return 0.0
    dist = distance_transform_edt(~occ) * mapped.resolution
    gx, gy = _cell_of(mapped, pts[:, 0], pts[:, 1])
    col, row = np.floor(gx).astype(np.int64), np.floor(gy).astype(np.int64)
    h, w = occ.shape
    inside = (row >= 0) & (row < h) & (col >= 0) & (col < w)
    near = np.zeros(len(pts), dtype=bool)
    # The nearest mapped centre is within tol of this point's cell centre (+ half a true cell).
    slack = 0.5 * truth.resolution
    near[inside] = dist[row[inside], col[inside]] <= tol_m + slack
    return float(near.mean())


def score_map(
    truth: OccupancyGrid, mapped: OccupancyGrid, seen: np.ndarray, tol_m: float = MATCH_TOL_M
) -> MapScore:
    """Compare a SLAM map with the truth; ``seen``: true-grid mask of the cells the lidar hit."""
    if seen.shape != truth.data.shape:
        raise ValueError(f"seen mask {seen.shape} does not match the true grid {truth.data.shape}")
    pts = cell_centres(mapped, mapped.data >= OCCUPIED_MIN)
    dist = np.minimum(wall_distance(truth, pts), FAR_M)
    return MapScore(
        wall_distance_mean_m=float(dist.mean()) if len(dist) else FAR_M,
        wall_distance_median_m=float(np.median(dist)) if len(dist) else FAR_M,
        precision=float((dist <= tol_m).mean()) if len(dist) else 0.0,
        walls_found=walls_found(truth, seen, mapped, tol_m),
        mapped_cells=len(pts),
        seen_cells=int((seen & (truth.data >= OCCUPIED_MIN)).sum()),
    )
