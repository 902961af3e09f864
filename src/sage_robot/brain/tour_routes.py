"""Path lengths between places on the map, for planning tours (not for driving).

The map's free space is shrunk by the robot's radius (so a route never squeezes through a
gap the robot does not fit), coarsened to :data:`COARSE_CELL_M` cells (a cell is drivable
when any fine cell in it is) and searched with Dijkstra over 8-connected cells from every
place at once (:class:`RouteTable`). A place standing on a cell that is not drivable is
moved to the nearest one that is. Lengths are in metres; an unreachable pair is ``inf``.

numpy and scipy only, no bus: the tour node builds a table from the latched ``/map`` in a
worker thread (``clock.offload``) and asks it for each plan.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
from scipy import ndimage
from scipy.sparse import coo_matrix, csr_matrix
from scipy.sparse.csgraph import dijkstra

from sage_robot.core.mapio import FREE, world_to_cell
from sage_robot.core.msgs import OccupancyGrid

COARSE_CELL_M = 0.25  # planning cell (m): fine enough for doors, coarse enough for a fast search
SNAP_CELLS = 40  # a place is moved at most this many coarse cells to a drivable one
_STEPS = ((0, 1, 1.0), (1, 0, 1.0), (1, 1, math.sqrt(2.0)), (1, -1, math.sqrt(2.0)))  # (drow, dcol, length)


def drivable_cells(grid: OccupancyGrid, radius_m: float) -> tuple[np.ndarray, int]:
    """Coarse drivable mask (row 0 at the origin's y) and the coarsening factor."""
    free = grid.data == FREE
    clearance_m = ndimage.distance_transform_edt(free) * grid.resolution
    fine = clearance_m >= radius_m
    f = max(1, round(COARSE_CELL_M / grid.resolution))
    rows, cols = -(-fine.shape[0] // f), -(-fine.shape[1] // f)
    padded = np.zeros((rows * f, cols * f), dtype=bool)
    padded[: fine.shape[0], : fine.shape[1]] = fine
    mask = np.asarray(padded.reshape(rows, f, cols, f).any(axis=(1, 3)), dtype=bool)
    return mask, f


def _graph(mask: np.ndarray, cell_m: float) -> csr_matrix:
    rows, cols = mask.shape
    index = np.arange(rows * cols).reshape(rows, cols)
    src, dst, w = [], [], []
    for dr, dc, length in _STEPS:
        r0, r1 = 0, rows - dr
        c0, c1 = max(0, -dc), cols - max(0, dc)
        a = mask[r0:r1, c0:c1] & mask[r0 + dr : r1 + dr, c0 + dc : c1 + dc]
        src.append(index[r0:r1, c0:c1][a])
        dst.append(index[r0 + dr : r1 + dr, c0 + dc : c1 + dc][a])
        w.append(np.full(int(a.sum()), length * cell_m))
    s, d, ww = np.concatenate(src), np.concatenate(dst), np.concatenate(w)
    n = rows * cols
    return coo_matrix((ww, (s, d)), shape=(n, n)).tocsr()


class RouteTable:
    """Path lengths (m) between named points on one map."""

    def __init__(
        self, grid: OccupancyGrid, points: Mapping[str, tuple[float, float]], radius_m: float
    ) -> None:
        self.grid = grid
        self.mask, self.factor = drivable_cells(grid, radius_m)
        self.cell_m = grid.resolution * self.factor
        self.graph = _graph(self.mask, self.cell_m)
        self.names = list(points)
        self.nodes = [self.node(*points[n]) for n in self.names]
        reachable = [i for i, node in enumerate(self.nodes) if node is not None]
        self.table = np.full((len(self.names), self.mask.size), np.inf)
        if reachable:
            found = dijkstra(self.graph, directed=False, indices=[self.nodes[i] for i in reachable])
            self.table[reachable] = np.atleast_2d(found)
        self._row = {n: i for i, n in enumerate(self.names)}

    def node(self, x: float, y: float) -> int | None:
        """The drivable coarse cell nearest to (x, y) m, or None when none is near."""
        row, col = world_to_cell(self.grid, x, y)
        r, c = int(row) // self.factor, int(col) // self.factor
        rows, cols = self.mask.shape
        for ring in range(SNAP_CELLS + 1):
            lo_r, lo_c = max(0, r - ring), max(0, c - ring)
            window = self.mask[lo_r : min(rows, r + ring + 1), lo_c : min(cols, c + ring + 1)]
            if window.any():
                rr, cc = np.nonzero(window)
                k = int(np.argmin((rr + lo_r - r) ** 2 + (cc + lo_c - c) ** 2))
                return int((rr[k] + lo_r) * cols + cc[k] + lo_c)
        return None

    def between(self, a: str, b: str) -> float:
        """Path length (m) from place ``a`` to place ``b`` (``inf`` when unreachable)."""
        node = self.nodes[self._row[b]]
        return math.inf if node is None else float(self.table[self._row[a], node])

    def from_point(self, x: float, y: float) -> dict[str, float]:
        """Path lengths (m) from (x, y) to every place (one more search)."""
        start = self.node(x, y)
        if start is None:
            return {n: math.inf for n in self.names}
        found = dijkstra(self.graph, directed=False, indices=start)
        pairs = zip(self.names, self.nodes, strict=True)
        return {n: math.inf if node is None else float(found[node]) for n, node in pairs}
