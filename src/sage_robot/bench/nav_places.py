"""Places and unmapped boxes for the nav benchmark on any map (no waypoints file needed).

The robot's free space: cells of the map that are known free and outside any keepout zone
(unknown space, walls and keepout count as blocked; so does everything beyond the image).
A cell is *passable* when its clearance (the distance from its centre to the nearest blocked
cell, less half a cell) is at least the robot's radius plus ``PASSAGE_MARGIN_M``: a gap of the
robot's width + 2 x ``PASSAGE_MARGIN_M`` lets it through. The robot's *reachable* space is the
largest 4-connected set of passable cells: speckles of free space (tiny islands in a SLAM map)
and rooms behind gaps the robot does not fit through are not in it.

``auto_places`` chooses N places by farthest-point sampling of the reachable cells that have
``PLACE_CLEARANCES_M`` of room around the robot: the first one (the dock) is drawn with the
seeded generator, each next one is the cell farthest (straight line) from those chosen so far.
The same map, N and seed give the same places.

``place_boxes`` drops K boxes into the reachable space, each clear of walls, other boxes and
the places, and keeps one only if every place can still reach every other through passable
cells of the map with the boxes in it; a box that would cut them apart is drawn again.

Pure numpy + scipy; map frame, metres, radians.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml
from scipy import ndimage

from sage_robot.core.errors import ConfigError
from sage_robot.core.mapio import FREE
from sage_robot.core.msgs import OccupancyGrid

PASSAGE_MARGIN_M = 0.1  # passable: clearance >= robot radius + this (a gap of width + 0.2 m)
PLACE_CLEARANCES_M = (0.45, 0.3, 0.2, PASSAGE_MARGIN_M)  # a place has robot radius + the first of
# these that fits the places MIN_SEPARATION_M apart, of room around it
MIN_SEPARATION_M = 1.5  # auto places closer than this to each other are an error (map too small)
BOX_WALL_CLEARANCE_M = 1.2  # a box's centre stays this far from walls and other boxes
BOX_PLACE_CLEARANCE_M = 1.2  # ... and from every place
BOX_SIZE_M = (0.6, 0.4)  # length along yaw, depth
BOX_TRIES_PER_BOX = 40  # draws per box before the benchmark makes do with fewer
DOCK = "DOCKING_STATION"
_FOUR = ndimage.generate_binary_structure(2, 1)


@dataclass(frozen=True)
class Box:
    x: float
    y: float
    yaw: float


@dataclass(frozen=True)
class FreeSpace:
    """The map as the robot's free space: ``blocked`` (rows, cols) is True for walls, unknown
    space and keepout zones."""

    grid: OccupancyGrid
    blocked: np.ndarray

    @property
    def res(self) -> float:
        return float(self.grid.resolution)

    def to_cell(self, x: float, y: float) -> tuple[int, int]:
        o = self.grid.origin
        return math.floor((y - o.y) / self.res), math.floor((x - o.x) / self.res)

    def to_xy(self, row: int, col: int) -> tuple[float, float]:
        o = self.grid.origin
        return float(o.x + (col + 0.5) * self.res), float(o.y + (row + 0.5) * self.res)

    def clearance(self, blocked: np.ndarray | None = None) -> np.ndarray:
        """Metres from each cell's centre to the nearest blocked cell's edge (0 when blocked);
        the map's border counts as blocked."""
        b = self.blocked if blocked is None else blocked
        edt = ndimage.distance_transform_edt(np.pad(~b, 1, constant_values=False))[1:-1, 1:-1]
        return np.maximum(np.asarray(edt) - 0.5, 0.0) * self.res


def free_space(grid: OccupancyGrid, keepout: OccupancyGrid | None = None) -> FreeSpace:
    """The robot's free space on ``grid``: known-free cells outside ``keepout``'s zones."""
    blocked = np.asarray(grid.data) != FREE
    if keepout is not None:
        from sage_robot.nav.costmap import OCCUPIED_MIN, GridGeometry, resample_mask

        blocked = blocked | (resample_mask(keepout, GridGeometry.of(grid), fill=0) >= OCCUPIED_MIN)
    return FreeSpace(grid, blocked)


def reachable(space: FreeSpace, radius_m: float, blocked: np.ndarray | None = None,
              clearance: np.ndarray | None = None) -> np.ndarray:
    """The largest 4-connected set of cells where the robot's centre fits (bool, rows x cols)."""
    clear = space.clearance(blocked) if clearance is None else clearance
    labels, n = ndimage.label(clear >= radius_m + PASSAGE_MARGIN_M, structure=_FOUR)
    if n == 0:
        return np.zeros(space.blocked.shape, bool)
    sizes = np.bincount(labels.ravel())
    sizes[0] = 0
    return np.asarray(labels == int(np.argmax(sizes)))


def connected(space: FreeSpace, radius_m: float, points: list[tuple[float, float]],
              blocked: np.ndarray | None = None) -> bool:
    """Whether the robot can drive between every two of ``points`` (passable cells only)."""
    clear = space.clearance(blocked)
    labels, _ = ndimage.label(clear >= radius_m + PASSAGE_MARGIN_M, structure=_FOUR)
    ids = set()
    h, w = labels.shape
    for x, y in points:
        r, c = space.to_cell(x, y)
        if not (0 <= r < h and 0 <= c < w) or labels[r, c] == 0:
            return False
        ids.add(int(labels[r, c]))
    return len(ids) <= 1


def auto_places(space: FreeSpace, n: int, radius_m: float, rng: np.random.Generator,
                accept: Callable[[float, float], bool] | None = None) -> list[tuple[float, float]]:
    """``n`` well-separated reachable places (x, y), the dock first (see the module doc).
    ``accept`` (optional, e.g. a planner check from the dock) may turn a candidate down; the
    next farthest is taken then. Places get the most room (``PLACE_CLEARANCES_M``, tried in
    turn) at which ``n`` of them still fit ``MIN_SEPARATION_M`` apart: small maps (the TurtleBot
    sandbox) have little room anywhere."""
    if n < 2:
        raise ConfigError(f"--places auto needs two or more places, got {n}")
    clear = space.clearance()
    reach = reachable(space, radius_m, clearance=clear)
    u = float(rng.random())  # one draw: the dock's cell, whatever room the places get
    best: list[tuple[float, float]] = []
    for room_m in PLACE_CLEARANCES_M:
        cells = np.argwhere(reach & (clear >= radius_m + room_m))
        if len(cells) == 0:
            continue
        chosen = _farthest(space, cells, n, min(int(u * len(cells)), len(cells) - 1), accept)
        if len(chosen) == n and min_separation(chosen) >= MIN_SEPARATION_M:
            return chosen
        if (len(chosen), min_separation(chosen)) > (len(best), min_separation(best)):
            best = chosen
    raise ConfigError(f"{n} places do not fit {MIN_SEPARATION_M:g} m apart on the map's reachable "
                      f"free space (the best try: {len(best)} places, the closest two "
                      f"{min_separation(best):.2f} m apart): ask for fewer")


def _farthest(space: FreeSpace, cells: np.ndarray, n: int, first: int,
              accept: Callable[[float, float], bool] | None) -> list[tuple[float, float]]:
    """Farthest-point sampling of ``cells`` (k, 2 rows/cols) from ``cells[first]``."""
    xy = np.column_stack([space.grid.origin.x + (cells[:, 1] + 0.5) * space.res,
                          space.grid.origin.y + (cells[:, 0] + 0.5) * space.res])
    ok = np.ones(len(xy), bool)
    chosen: list[tuple[float, float]] = []
    nearest = np.full(len(xy), np.inf)
    i = first
    while len(chosen) < n:
        x, y = float(xy[i, 0]), float(xy[i, 1])
        ok[i] = False
        if accept is None or not chosen or accept(x, y):
            chosen.append((x, y))
            nearest = np.minimum(nearest, np.hypot(xy[:, 0] - x, xy[:, 1] - y))
        if not ok.any():
            break
        i = int(np.argmax(np.where(ok, nearest, -1.0)))
    return chosen


def min_separation(points: list[tuple[float, float]]) -> float:
    return min((math.hypot(a[0] - b[0], a[1] - b[1]) for i, a in enumerate(points) for b in points[i + 1:]),
               default=math.inf)


def place_names(n: int) -> list[str]:
    return [DOCK] + [f"PLACE_{i}" for i in range(1, n)]


def write_waypoints(path: Path, points: list[tuple[float, float]], source: str) -> Path:
    """A waypoints file (the package's own format) for ``points``: the dock first."""
    places = [{"name": name, "pose": [round(x, 3), round(y, 3), 0.0],
               "description": f"chosen automatically on {source}"}
              for name, (x, y) in zip(place_names(len(points)), points, strict=True)]
    path.write_text(yaml.safe_dump({"places": places}, sort_keys=False), encoding="utf-8")
    return path


def box_cells(space: FreeSpace, box: Box, size: tuple[float, float] = BOX_SIZE_M) -> np.ndarray:
    """The cells a box covers, (k, 2) rows/cols: every cell whose square it touches (about)."""
    half = 0.5 * math.hypot(*size) + space.res
    r0, c0 = space.to_cell(box.x - half, box.y - half)
    r1, c1 = space.to_cell(box.x + half, box.y + half)
    h, w = space.blocked.shape
    rows, cols = np.mgrid[max(r0, 0):min(r1 + 1, h), max(c0, 0):min(c1 + 1, w)]
    x = space.grid.origin.x + (cols + 0.5) * space.res - box.x
    y = space.grid.origin.y + (rows + 0.5) * space.res - box.y
    c, s = math.cos(box.yaw), math.sin(box.yaw)
    pad = 0.5 * space.res
    inside = (np.abs(c * x + s * y) <= size[0] / 2 + pad) & (np.abs(-s * x + c * y) <= size[1] / 2 + pad)
    return np.column_stack([rows[inside], cols[inside]])


def place_boxes(space: FreeSpace, k: int, places: list[tuple[float, float]], radius_m: float,
                rng: np.random.Generator) -> tuple[list[Box], bool]:
    """Up to ``k`` boxes that leave a path between every two places (see the module doc), and
    whether the places are connected with all of them in (False only if they were not before)."""
    blocked = space.blocked.copy()
    boxes: list[Box] = []
    if not connected(space, radius_m, places, blocked):
        return boxes, False
    tries = 0
    while len(boxes) < k and tries < BOX_TRIES_PER_BOX * k:
        tries += 1
        clear = space.clearance(blocked)
        room = reachable(space, radius_m, blocked, clear) & (clear >= BOX_WALL_CLEARANCE_M)
        cells = np.argwhere(room)
        if len(cells) == 0:
            break
        r, c = cells[rng.integers(len(cells))]
        x, y = space.to_xy(int(r), int(c))
        yaw = float(rng.uniform(0, math.pi))
        if any(math.hypot(px - x, py - y) <= BOX_PLACE_CLEARANCE_M for px, py in places):
            continue
        box = Box(x, y, yaw)
        trial = blocked.copy()
        cov = box_cells(space, box)
        trial[cov[:, 0], cov[:, 1]] = True
        if connected(space, radius_m, places, trial):
            boxes.append(box)
            blocked = trial
    return boxes, connected(space, radius_m, places, blocked)
