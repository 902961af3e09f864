"""Occupancy grids for tests, drawn by hand.

A drawing reads as a map image: ``#`` wall, ``.`` free, ``?`` unknown, and the top line is the
far (+y) edge. In the grid's data, row 0 is the bottom (-y) edge, as in ``OccupancyGrid``.
Rectangles (``fill``) are given in map metres and cover the cells from ``floor`` of the lower
edge up to, not including, ``floor`` of the upper one.
"""

from __future__ import annotations

import numpy as np

from sage_robot.core.msgs import OccupancyGrid, Pose2D

WALL, FREE, UNKNOWN = 100, 0, -1
CODES = {"#": WALL, ".": FREE, "?": UNKNOWN}


def grid_of(data: np.ndarray, resolution: float = 0.05, origin: tuple[float, float] = (0.0, 0.0),
         theta: float = 0.0) -> OccupancyGrid:
    """A map-frame grid of ``data`` (row 0 the bottom), stamped 0."""
    return OccupancyGrid(0.0, "map", resolution, Pose2D(origin[0], origin[1], theta),
                         np.ascontiguousarray(data, dtype=np.int8))


def blank(rows: int, cols: int, resolution: float = 0.05, origin: tuple[float, float] = (0.0, 0.0), *,
          theta: float = 0.0, value: int = FREE) -> OccupancyGrid:
    """A grid of ``rows`` × ``cols`` cells, all ``value``."""
    return grid_of(np.full((rows, cols), value, dtype=np.int8), resolution, origin, theta)


def draw(picture: str, resolution: float, scale: int = 1,
         origin: tuple[float, float] = (0.0, 0.0)) -> OccupancyGrid:
    """A grid from a drawing; each character becomes ``scale`` × ``scale`` cells."""
    rows = [line.strip() for line in picture.strip().splitlines()]
    data = np.array([[CODES[ch] for ch in row] for row in rows], dtype=np.int8)[::-1]
    if scale != 1:
        data = np.kron(data, np.ones((scale, scale), dtype=np.int8))
    return grid_of(data, resolution, origin)


def room(width_m: float, height_m: float, resolution: float = 0.05, wall_cells: int = 1,
         origin: tuple[float, float] = (0.0, 0.0)) -> OccupancyGrid:
    """An empty rectangular room whose walls are ``wall_cells`` thick, inside the grid's edge."""
    g = blank(round(height_m / resolution), round(width_m / resolution), resolution, origin)
    k = wall_cells
    g.data[:k, :] = g.data[-k:, :] = g.data[:, :k] = g.data[:, -k:] = WALL
    return g


def fill(g: OccupancyGrid, x0: float, y0: float, x1: float, y1: float, value: int = WALL) -> OccupancyGrid:
    """Set the cells of the map rectangle (x0, y0)–(x1, y1) to ``value``, in place; returns ``g``.

    For an unrotated grid: walls and pillars (``WALL``), corridors carved out of rock (``FREE``),
    zones of a mask (any value).
    """
    ox, oy = g.origin.x, g.origin.y
    c0, c1 = sorted((int((x0 - ox) / g.resolution), int((x1 - ox) / g.resolution)))
    r0, r1 = sorted((int((y0 - oy) / g.resolution), int((y1 - oy) / g.resolution)))
    g.data[max(r0, 0):max(r1, 0), max(c0, 0):max(c1, 0)] = value
    return g


def blank_like(g: OccupancyGrid, value: int = FREE) -> OccupancyGrid:
    """A grid of the same size, resolution and origin as ``g``, all ``value`` (e.g. for a mask)."""
    return blank(g.height, g.width, g.resolution, (g.origin.x, g.origin.y), theta=g.origin.theta, value=value)
