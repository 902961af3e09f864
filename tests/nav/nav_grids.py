"""Hand-drawn grids for navigation tests: '#' wall, '.' free, '?' unknown. Row 0 of the
drawing is the TOP (far +y) edge, as a map image reads."""

from __future__ import annotations

import numpy as np

from sage_robot.core.msgs import OccupancyGrid, Pose2D

CODES = {"#": 100, ".": 0, "?": -1}


def draw(picture: str, resolution: float = 0.1, scale: int = 1) -> OccupancyGrid:
    """A grid from a drawing; each character becomes ``scale`` × ``scale`` cells."""
    rows = [line.strip() for line in picture.strip().splitlines()]
    data = np.array([[CODES[ch] for ch in row] for row in rows], dtype=np.int8)[::-1]
    data = np.kron(data, np.ones((scale, scale), dtype=np.int8))
    return OccupancyGrid(0.0, "map", resolution, Pose2D(0.0, 0.0, 0.0), data)


def room(width_m: float, height_m: float, resolution: float = 0.05) -> OccupancyGrid:
    """An empty rectangular room with one-cell walls; origin at (0, 0)."""
    w, h = round(width_m / resolution), round(height_m / resolution)
    data = np.zeros((h, w), dtype=np.int8)
    data[0, :] = data[-1, :] = data[:, 0] = data[:, -1] = 100
    return OccupancyGrid(0.0, "map", resolution, Pose2D(0.0, 0.0, 0.0), data)
