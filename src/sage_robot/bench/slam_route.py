"""Drives for the SLAM simulation bench: the shipped building's corridors, or an automatic tour.

``auto_route`` works on any occupancy map: it picks well-spread stops in the free space the
robot fits in (farthest-point sampling from the start, the most open spot of the largest free
region, until no free spot is more than ``stop_spacing_m`` from a stop), orders them
nearest-first, returns to the start, and joins them with paths planned by ``nav.planner`` on
the map's costmap. ``drive_poses`` turns a route into the poses of the scans: one every
``step_m`` of travel, turning on the spot (``turn_step_rad`` per scan) where the heading
changes by more than that. Map frame, metres, radians.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

Pose = tuple[float, float, float]

ROUTE_CLEARANCE_M = 0.6  # stops keep this far from walls and unknown space...
MIN_CLEARANCE_M = 0.35  # ...or, in a cramped map, half the most open spot's clearance, not below this
STOP_SPACING_M = 8.0  # sample stops until every reachable free spot is this close to one...
MIN_STOP_SPACING_M = 1.5  # ...or a third of the free region's size in a small map, not below this
MAX_STOPS = 40
ROBOT_INSCRIBED_M, INFLATION_M, COST_SCALING = 0.25, 0.55, 3.0
HEADING_LOOKAHEAD = 3  # points ahead used for the heading of a resampled path (smooths kinks)


def corridor_route() -> list[tuple[float, float]]:
    """Waypoints (m) of the scripted drive through the shipped building's corridors."""
    from sage_robot.sim.building import CORRIDOR_END_M, EW_Y, NS_X, SIZE_M

    ew, ns = sum(EW_Y) / 2, sum(NS_X) / 2
    west, east = CORRIDOR_END_M + 4.0, SIZE_M[0] - CORRIDOR_END_M - 4.0
    south, north = CORRIDOR_END_M + 4.0, SIZE_M[1] - CORRIDOR_END_M - 4.0
    return [(west, ew), (east, ew), (ns, ew), (ns, north), (ns, south)]


def _open_space(grid: Any) -> np.ndarray:
    """Distance (m) from each cell to the nearest cell that is not known free."""
    from scipy.ndimage import distance_transform_edt

    dist: np.ndarray = distance_transform_edt(grid.data == 0) * grid.resolution
    return dist


def _cells_to_world(grid: Any, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    xs = grid.origin.x + (cols + 0.5) * grid.resolution
    ys = grid.origin.y + (rows + 0.5) * grid.resolution
    return np.column_stack((xs, ys))


def pick_stops(grid: Any, spacing_m: float = STOP_SPACING_M, max_stops: int = MAX_STOPS) -> np.ndarray:
    """(K, 2) stops, the first the most open spot of the largest free region (m)."""
    from scipy.ndimage import label

    from sage_robot.core.errors import ConfigError

    dist = _open_space(grid)
    clearance = max(MIN_CLEARANCE_M, min(ROUTE_CLEARANCE_M, 0.5 * float(dist.max())))
    labels, n = label(dist >= clearance)
    if n == 0:
        raise ConfigError(f"the map has no free space {clearance:.2f} m clear of walls for a drive")
    sizes = np.bincount(labels.ravel())[1:]
    region = labels == 1 + int(np.argmax(sizes))
    rows, cols = np.nonzero(region)
    size_m = float(np.hypot(np.ptp(rows), np.ptp(cols))) * grid.resolution
    spacing_m = max(MIN_STOP_SPACING_M, min(spacing_m, size_m / 3))
    pts = _cells_to_world(grid, rows, cols)
    first = int(np.argmax(dist[rows, cols]))
    chosen = [first]
    gap = np.hypot(*(pts - pts[first]).T)
    while len(chosen) < max_stops:
        far = int(np.argmax(gap))
        if gap[far] < spacing_m:
            break
        chosen.append(far)
        gap = np.minimum(gap, np.hypot(*(pts - pts[far]).T))
    return pts[chosen]


def order_stops(stops: np.ndarray) -> np.ndarray:
    """Nearest-first tour from the first stop, back to it at the end."""
    left = list(range(1, len(stops)))
    order = [0]
    while left:
        here = stops[order[-1]]
        k = min(left, key=lambda i: float(np.hypot(*(stops[i] - here))))
        left.remove(k)
        order.append(k)
    order.append(0)
    return stops[order]


def auto_route(grid: Any, spacing_m: float = STOP_SPACING_M) -> list[tuple[float, float]]:
    """A planned tour through the map's free space that returns to its start (m)."""
    from sage_robot.nav.costmap import Costmap
    from sage_robot.nav.planner import NoPath, plan

    costmap = Costmap.from_grid(grid, ROBOT_INSCRIBED_M, INFLATION_M, COST_SCALING)
    tour = order_stops(pick_stops(grid, spacing_m))
    points: list[tuple[float, float]] = [(float(tour[0, 0]), float(tour[0, 1]))]
    for goal in tour[1:]:
        try:
            leg = plan(costmap, points[-1], (float(goal[0]), float(goal[1])))
        except NoPath:
            continue  # a stop the planner cannot reach from here: skip it
        points += [(float(x), float(y)) for x, y in leg.points[1:]]
    return points


def drive_poses(
    route: list[tuple[float, float]],
    step_m: float,
    turn_step_rad: float,
    max_length_m: float | None = None,
) -> list[Pose]:
    """Scan poses along ``route``: one per ``step_m`` of travel, on-the-spot turns between."""
    from sage_robot.nav.planner import resample

    pts = resample(np.asarray(route, dtype=np.float64), step_m)
    if len(pts) < 2:
        return [(float(pts[0, 0]), float(pts[0, 1]), 0.0)] if len(pts) else []
    ahead = np.minimum(np.arange(len(pts)) + HEADING_LOOKAHEAD, len(pts) - 1)
    delta = pts[ahead] - pts
    headings = np.arctan2(delta[:, 1], delta[:, 0])
    for k in range(len(pts) - 2, -1, -1):  # the last points look back
        if not delta[k].any():
            headings[k] = headings[k + 1]
    headings[-1] = headings[-2]
    poses: list[Pose] = [(float(pts[0, 0]), float(pts[0, 1]), float(headings[0]))]
    travelled = 0.0
    for k in range(1, len(pts)):
        heading = poses[-1][2]
        turn = math.remainder(float(headings[k]) - heading, 2 * math.pi)
        x, y = poses[-1][:2]
        for j in range(1, int(abs(turn) / turn_step_rad) + 1):
            poses.append((x, y, heading + math.copysign(j * turn_step_rad, turn)))
        travelled += math.hypot(pts[k, 0] - x, pts[k, 1] - y)
        if max_length_m is not None and travelled > max_length_m:
            break
        poses.append((float(pts[k, 0]), float(pts[k, 1]), float(headings[k])))
    return poses
