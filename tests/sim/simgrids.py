"""Hand-drawn grids for the simulator's tests (a helper module, not a test)."""

from __future__ import annotations

import numpy as np

from sage_robot.core.msgs import OccupancyGrid, Pose2D


def grid_from_art(
    art: str, resolution: float = 1.0, origin: tuple[float, float] = (0.0, 0.0)
) -> OccupancyGrid:
    """'#' = wall, '.' = free, '?' = unknown; the top line of the drawing is the far (+y) edge."""
    lines = [ln.strip() for ln in art.strip().splitlines()]
    table = {"#": 100, ".": 0, "?": -1}
    data = np.array([[table[c] for c in ln] for ln in lines], dtype=np.int8)[::-1].copy()
    return OccupancyGrid(0.0, "map", resolution, Pose2D(origin[0], origin[1], 0.0), data)
