"""A costmap as an :class:`OccupancyGrid` message, for the operator's map (``/nav/costmap``).

Values as Nav2's costmap publisher gives them: free 0, the inflated band 1..98, inscribed 99,
lethal 100 (walls, scan obstacles with their pads: people's legs), no information -1. A grid
wider than :data:`COSTMAP_MAX_CELLS` is shrunk by whole-cell blocks keeping each block's highest
cost, so an obstacle never disappears from the shrunk picture.
"""

from __future__ import annotations

import math

import numpy as np

from sage_robot.core.msgs import OccupancyGrid, Pose2D
from sage_robot.nav.costmap import INSCRIBED, LETHAL, MAX_NON_OBSTACLE, NO_INFORMATION, Costmap

COSTMAP_MAX_CELLS = 160  # cells per side of the published grid, at most (the page draws it)
INFLATED_MAX = 98  # the inflated band's highest value on the 0..100 scale
INSCRIBED_VALUE = 99
LETHAL_VALUE = 100


def occupancy_values(cost: np.ndarray) -> np.ndarray:
    """Costmap costs (uint8 0..255) → occupancy values (int8: -1, 0..100)."""
    c = np.asarray(cost).astype(np.int32)
    out = np.zeros(c.shape, dtype=np.int8)
    band = (c > 0) & (c <= MAX_NON_OBSTACLE)
    out[band] = (1 + (c[band] - 1) * (INFLATED_MAX - 1) // (MAX_NON_OBSTACLE - 1)).astype(np.int8)
    out[c == INSCRIBED] = INSCRIBED_VALUE
    out[c == LETHAL] = LETHAL_VALUE
    out[c == NO_INFORMATION] = -1
    return out


def shrink(values: np.ndarray, factor: int) -> np.ndarray:
    """Blocks of ``factor`` × ``factor`` cells → their highest value (unknown only when all are)."""
    if factor <= 1:
        return values
    rows, cols = (math.ceil(n / factor) * factor for n in values.shape)
    padded = np.full((rows, cols), -1, dtype=np.int8)
    padded[: values.shape[0], : values.shape[1]] = values
    blocks = padded.reshape(rows // factor, factor, cols // factor, factor)
    out: np.ndarray = blocks.max(axis=(1, 3)).astype(np.int8)
    return out


def costmap_grid(cm: Costmap, stamp: float, frame_id: str = "map",
                 max_cells: int = COSTMAP_MAX_CELLS) -> OccupancyGrid:
    """``cm``'s combined, inflated cost as a message, at most ``max_cells`` per side."""
    if max_cells < 1:
        raise ValueError(f"max_cells must be at least 1, not {max_cells}")
    g = cm.geom
    factor = max(1, math.ceil(max(g.shape) / max_cells))
    data = shrink(occupancy_values(cm.cost), factor)
    return OccupancyGrid(stamp, frame_id, g.resolution * factor, Pose2D(g.origin_x, g.origin_y, 0.0), data)
