"""Global planner: cost-aware shortest path on the inflated costmap, then smoothed.

The search runs in compiled code: ``pyastar2d`` (A* in C++, 8-connected) when it is
installed, else scikit-image's ``graph.MCP_Geometric`` (Dijkstra in Cython). A cell's
step weight is ``1 + COST_WEIGHT * cost / 252`` (NavFn's cost-aware metric), more in gaps
narrower than the robot's width + 0.2 m (``NARROW_WEIGHT``: used when there is no wider way);
cells at or above ``INSCRIBED`` cannot be entered. Large maps are searched on a coarser grid (each
planning cell takes the *highest* cost of the fine cells it covers, so a coarse path never
crosses a wall the fine map has; but a cell with any passable fine cell stays passable, and a
path through such a cell is found on the fine grid near the coarse one, so pooling never
closes a gap the robot fits through) and the result is smoothed on the fine costmap.

Conventions: paths are (N, 2) float arrays of map-frame (x, y) in metres; grid axes as in
:mod:`sage_robot.nav.costmap`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from sage_robot.nav.costmap import INSCRIBED, MAX_NON_OBSTACLE, NO_INFORMATION, Costmap

COST_WEIGHT = 3.0  # extra step weight at cost 252 (so the path keeps off walls)
MAX_FINE_CELLS = 400_000  # above this many cells, plan on a coarser grid
PATH_SPACING_M = 0.05  # spacing of the returned path's points (m)
SMOOTH_ITERATIONS = 2  # line-of-sight shortcut passes
LINE_CHECK_STEP_CELLS = 0.25  # shortcut lines are checked every quarter cell
BAND_M = 1.0  # a coarse path through a narrow gap is refined on the fine grid this near it (m)
GOAL_SEARCH_RADIUS_M = 0.3  # a goal inside an inflated cell moves to the nearest free one within this
# Gaps narrower than the robot's width + 2 x NARROW_MARGIN_M are a last resort (issue #20: in the
# TurtleBot sandbox the shortest way ran between a pillar and the wall with 3 cm to spare each
# side; the robot scraped the wall or stopped there for good, while a way 0.7 m wide was free):
# each step through one weighs NARROW_WEIGHT more, about 0.5 m of detour per 5 cm cell.
NARROW_MARGIN_M = 0.1
NARROW_WEIGHT = 10.0
# ... and up to NARROW_DEPTH_WEIGHT more, in proportion to how far the cell's cost lies above
# that, so a path through a gap keeps to its middle: the costs across a narrow gap differ by a
# few units only (240 in the middle, 248 at the sides of the TurtleBot sandbox's 0.85 m gap
# between a pillar and the wall), and with one flat weight the path hugged the inside of the
# gap's bend, 14 cm off its middle, where the controller and the collision guard stopped it.
NARROW_DEPTH_WEIGHT = 60.0
# A robot that stands in unexplored space (a SLAM map's unknown patch the controller cut
# through: measured on willow-2010, where every later goal failed "boxed in") plans its way out
# over at most this much of it, on cells its body fits in, at the step weight of a narrow gap.
ESCAPE_UNKNOWN_M = 1.5
BOXED_IN = "the robot is boxed in where it stands"


class NoPath(Exception):
    """No collision-free path; the message says why, for a person."""


@dataclass(frozen=True)
class Plan:
    points: np.ndarray  # (N, 2) map-frame x, y (m)
    length_m: float


def _astar_backend() -> object | None:
    try:
        import pyastar2d  # type: ignore[import-not-found, unused-ignore]
    except ImportError:
        return None
    backend: object = pyastar2d
    return backend


def _pool_max(cost: np.ndarray, f: int) -> np.ndarray:
    """Max-pool ``cost`` by ``f`` (pads with the unknown cost)."""
    if f == 1:
        return cost
    rows, cols = cost.shape
    pr, pc = -rows % f, -cols % f
    padded = np.pad(cost, ((0, pr), (0, pc)), constant_values=255)
    out: np.ndarray = padded[0::f, 0::f].copy()
    for i in range(f):  # strided slices: far faster than a reshaped max over two axes
        for j in range(f):
            if i or j:
                np.maximum(out, padded[i::f, j::f], out=out)
    return out


def narrow_cost(costmap: Costmap) -> int:
    """The inflation cost at ``NARROW_MARGIN_M`` beyond the inscribed radius: cells costlier
    than this lie in a gap narrower than the robot's width + 2 x NARROW_MARGIN_M."""
    if costmap.inflation_m <= costmap.inscribed_m + NARROW_MARGIN_M:
        return MAX_NON_OBSTACLE
    return int(MAX_NON_OBSTACLE * math.exp(-costmap.cost_scaling * NARROW_MARGIN_M))


def weights_from_cost(cost: np.ndarray, narrow: int = MAX_NON_OBSTACLE) -> np.ndarray:
    """Step weights: ``1 + COST_WEIGHT * cost / 252``, plus ``NARROW_WEIGHT`` on cells costlier
    than ``narrow`` (a gap the robot barely fits: a last resort) and up to ``NARROW_DEPTH_WEIGHT``
    more the costlier they are (keep to the gap's middle), inscribed cells impassable."""
    w: np.ndarray = (
        1.0 + COST_WEIGHT * np.minimum(cost, MAX_NON_OBSTACLE).astype(np.float32) / MAX_NON_OBSTACLE
    )
    tight = cost > narrow
    depth = (np.minimum(cost[tight], MAX_NON_OBSTACLE).astype(np.float32) - narrow) / max(
        MAX_NON_OBSTACLE - narrow, 1)
    w[tight] += NARROW_WEIGHT + NARROW_DEPTH_WEIGHT * depth
    w[cost >= INSCRIBED] = np.inf
    return w.astype(np.float32)


def _nearest_free(weights: np.ndarray, cell: tuple[int, int], radius: int) -> tuple[int, int] | None:
    r, c = cell
    if 0 <= r < weights.shape[0] and 0 <= c < weights.shape[1] and np.isfinite(weights[r, c]):
        return cell
    best, best_d = None, math.inf
    for dr in range(-radius, radius + 1):
        for dc in range(-radius, radius + 1):
            rr, cc = r + dr, c + dc
            if 0 <= rr < weights.shape[0] and 0 <= cc < weights.shape[1] and np.isfinite(weights[rr, cc]):
                d = dr * dr + dc * dc
                if d < best_d:
                    best, best_d = (rr, cc), d
    return best


def _search(weights: np.ndarray, start: tuple[int, int], goal: tuple[int, int]) -> np.ndarray | None:
    astar = _astar_backend()
    if astar is not None:
        path = astar.astar_path(weights, start, goal, allow_diagonal=True)  # type: ignore[attr-defined]
        return None if path is None else np.asarray(path)
    from skimage.graph import MCP_Geometric

    mcp = MCP_Geometric(np.where(np.isfinite(weights), weights, -1.0))
    costs, _ = mcp.find_costs([start], [goal])
    if not np.isfinite(costs[goal]):
        return None
    return np.asarray(mcp.traceback(goal))


def _line_free(costmap: Costmap, a: np.ndarray, b: np.ndarray, limit: int) -> bool:
    n = max(2, int(np.hypot(*(b - a)) / (costmap.geom.resolution * LINE_CHECK_STEP_CELLS)) + 1)
    t = np.linspace(0.0, 1.0, n)[:, None]
    pts = a + (b - a) * t
    return bool((costmap.cost_at(pts[:, 0], pts[:, 1]) < limit).all())


def smooth(points: np.ndarray, costmap: Costmap) -> np.ndarray:
    """Shortcut the grid path where a straight line stays in cells no costlier than the ones the
    path already crosses (so it does not cut closer to walls) and passable (below
    ``INSCRIBED``: a path that starts in unknown space or in a wall's inscribed zone keeps its
    grid steps until it is out; issue #20: from a start in an unknown patch every line counted
    as free, and the plan became a straight line to the goal through the walls), then resample
    evenly."""
    if len(points) < 3:
        return resample(points, PATH_SPACING_M)
    out = points
    for _ in range(SMOOTH_ITERATIONS):
        costs = costmap.cost_at(out[:, 0], out[:, 1]).astype(np.int32)
        keep = [0]
        i = 0
        while i < len(out) - 1:
            j = len(out) - 1
            step = max(1, (len(out) - i) // 2)
            # furthest visible point, probed coarsely then linearly
            while j > i + 1:
                # never through an inscribed, lethal or unknown cell, even from a start in one
                limit = min(int(max(costs[i:j + 1].max(), 1)) + 1, INSCRIBED)
                if _line_free(costmap, out[i], out[j], limit):
                    break
                j = max(i + 1, j - step)
                step = max(1, step // 2)
            keep.append(j)
            i = j
        out = out[keep]
    return resample(out, PATH_SPACING_M)


def resample(points: np.ndarray, spacing: float) -> np.ndarray:
    if len(points) < 2:
        return points.astype(np.float64)
    seg = np.hypot(*np.diff(points, axis=0).T)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    if s[-1] <= 0:
        return points[:1].astype(np.float64)
    n = max(2, math.ceil(s[-1] / spacing) + 1)
    t = np.linspace(0.0, s[-1], n)
    return np.column_stack([np.interp(t, s, points[:, 0]), np.interp(t, s, points[:, 1])])


def path_length(points: np.ndarray) -> float:
    return float(np.hypot(*np.diff(points, axis=0).T).sum()) if len(points) > 1 else 0.0


def _pool_min(cost: np.ndarray, f: int) -> np.ndarray:
    """Min-pool ``cost`` by ``f`` (pads with the unknown cost)."""
    rows, cols = cost.shape
    padded = np.pad(cost, ((0, -rows % f), (0, -cols % f)), constant_values=255)
    out: np.ndarray = padded[0::f, 0::f].copy()
    for i in range(f):
        for j in range(f):
            if i or j:
                np.minimum(out, padded[i::f, j::f], out=out)
    return out


def _fine_in_band(costmap: Costmap, cells: np.ndarray, f: int, start: tuple[float, float],
                  goal: tuple[float, float]) -> np.ndarray | None:
    """The fine-grid path from ``start`` to ``goal`` within ``BAND_M`` of a coarse path
    (``cells``, planning cells of ``f`` fine cells); None when there is none."""
    g = costmap.geom
    k = max(1, round(BAND_M / g.resolution))
    r0 = max(int(cells[:, 0].min()) * f - k, 0)
    c0 = max(int(cells[:, 1].min()) * f - k, 0)
    r1 = min((int(cells[:, 0].max()) + 1) * f + k, g.shape[0])
    c1 = min((int(cells[:, 1].max()) + 1) * f + k, g.shape[1])
    band = np.zeros((r1 - r0, c1 - c0), dtype=bool)
    for dr in range(f):
        for dc in range(f):
            rr, cc = cells[:, 0] * f + dr - r0, cells[:, 1] * f + dc - c0
            ok = (rr >= 0) & (rr < band.shape[0]) & (cc >= 0) & (cc < band.shape[1])
            band[rr[ok], cc[ok]] = True
    band = ndimage.binary_dilation(band, iterations=k)
    weights = weights_from_cost(costmap.cost[r0:r1, c0:c1], narrow_cost(costmap))
    weights[~band] = np.inf
    radius = max(1, round(GOAL_SEARCH_RADIUS_M / g.resolution))

    def cell(p: tuple[float, float]) -> tuple[int, int]:
        rc = g.to_cell(p[0], p[1])
        return int(rc[0]) - r0, int(rc[1]) - c0

    s, gl = _nearest_free(weights, cell(start), radius + 1), _nearest_free(weights, cell(goal), radius)
    if s is None or gl is None:
        return None
    found = _search(weights, s, gl)
    if found is None:
        return None
    xs, ys = g.to_world(found[:, 0] + r0, found[:, 1] + c0)
    out: np.ndarray = np.column_stack([xs, ys])
    return out


def _escape_unknown(costmap: Costmap, weights: np.ndarray, start: tuple[float, float]) -> np.ndarray:
    """``weights`` (the fine grid's) with the unknown cells within ESCAPE_UNKNOWN_M of
    ``start`` passable where the robot's body fits (no wall or obstacle within its inscribed
    radius), at a narrow gap's weight: the way out of unexplored space the robot stands in."""
    g = costmap.geom
    r, c = (int(v) for v in g.to_cell(start[0], start[1]))
    k = math.ceil(ESCAPE_UNKNOWN_M / g.resolution)
    r0, r1 = max(r - k, 0), min(r + k + 1, g.shape[0])
    c0, c1 = max(c - k, 0), min(c + k + 1, g.shape[1])
    if r0 >= r1 or c0 >= c1:
        return weights
    rr, cc = np.mgrid[r0:r1, c0:c1]
    near = np.hypot(rr - r, cc - c) <= k
    fits = costmap.dist[r0:r1, c0:c1] > costmap.inscribed_m
    way_out = near & fits & (costmap.cost[r0:r1, c0:c1] == NO_INFORMATION)
    out: np.ndarray = weights.copy()
    out[r0:r1, c0:c1][way_out] = 1.0 + COST_WEIGHT + NARROW_WEIGHT
    return out


def _start_cell(costmap: Costmap, weights: np.ndarray, start: tuple[float, float],
                at: tuple[int, int], radius: int) -> tuple[tuple[int, int], bool, np.ndarray]:
    """The free cell nearest ``start`` (its cell ``at``, on the grid of ``weights``), whether
    it was found only by escaping unexplored space, and the weights to search with then."""
    s = _nearest_free(weights, at, radius)
    if s is not None:
        return s, False, weights
    weights = _escape_unknown(costmap, weights, start)
    s = _nearest_free(weights, at, radius)
    if s is None:
        raise NoPath(BOXED_IN)
    return s, True, weights


def plan(costmap: Costmap, start: tuple[float, float], goal: tuple[float, float],
         max_cells: int = MAX_FINE_CELLS, fine_fallback: bool = True, open_pool: bool = True) -> Plan:
    """A smoothed path from ``start`` to ``goal`` (map frame, m). Raises :class:`NoPath`.

    On a coarse grid a planning cell that some fine cell inside makes passable stays passable
    (at the highest non-lethal cost), so pooling never closes a gap the fine grid has open;
    a coarse path through such a cell is then found on the fine grid within ``BAND_M`` of it
    (or, failing that, the strict max-pooled grid is searched). When the coarse grid finds no
    way, the fine grid is searched before giving up."""
    g = costmap.geom
    factor = max(1, math.ceil(math.sqrt(g.shape[0] * g.shape[1] / max_cells)))
    cost = _pool_max(costmap.cost, factor)
    rescued = None
    if factor > 1 and open_pool:
        rescued = (_pool_min(costmap.cost, factor) < INSCRIBED) & (cost >= INSCRIBED)
        cost = np.where(rescued, np.uint8(MAX_NON_OBSTACLE), cost)
    weights = weights_from_cost(cost, narrow_cost(costmap))
    res = g.resolution * factor
    radius = max(1, round(GOAL_SEARCH_RADIUS_M / res))

    def cell(p: tuple[float, float]) -> tuple[int, int]:
        return (int((p[1] - g.origin_y) // res), int((p[0] - g.origin_x) // res))

    if factor > 1 and _nearest_free(weights, cell(start), radius + 1) is None:
        # standing in unexplored space? its way out is found on the fine grid
        return plan(costmap, start, goal, max_cells=costmap.cost.size, fine_fallback=False)
    s, escaping, weights = _start_cell(costmap, weights, start, cell(start), radius + 1)
    gl = _nearest_free(weights, cell(goal), radius)
    if gl is None:
        raise NoPath("the goal is inside an obstacle or outside the map")
    cells = _search(weights, s, gl)
    if cells is not None and rescued is not None and rescued[cells[:, 0], cells[:, 1]].any():
        fine = _fine_in_band(costmap, cells, factor, start, goal)
        if fine is None:  # the pooled gap was no gap: plan as before on the strict coarse grid
            return plan(costmap, start, goal, max_cells, fine_fallback, open_pool=False)
        fine[0] = start
        if math.hypot(goal[0] - fine[-1, 0], goal[1] - fine[-1, 1]) <= GOAL_SEARCH_RADIUS_M + g.resolution:
            fine[-1] = goal
        fine = smooth(fine, costmap)
        return Plan(fine, path_length(fine))
    if cells is None:
        if escaping:
            raise NoPath(BOXED_IN)
        if factor > 1 and fine_fallback:
            # a gap narrower than a coarse cell may still be passable: search the fine grid
            return plan(costmap, start, goal, max_cells=costmap.cost.size, fine_fallback=False)
        raise NoPath("no free way to the goal")
    xs = g.origin_x + (cells[:, 1] + 0.5) * res
    ys = g.origin_y + (cells[:, 0] + 0.5) * res
    pts = np.column_stack([xs, ys])
    pts[0] = start
    if math.hypot(goal[0] - pts[-1, 0], goal[1] - pts[-1, 1]) <= GOAL_SEARCH_RADIUS_M + res:
        pts[-1] = goal
    pts = smooth(pts, costmap)
    return Plan(pts, path_length(pts))


def path_blocked(costmap: Costmap, points: np.ndarray, ahead_m: float) -> bool:
    """Whether the first ``ahead_m`` of a path runs into a lethal/inscribed cell."""
    if len(points) == 0:
        return False
    n = len(points) if math.isinf(ahead_m) else max(1, int(ahead_m / PATH_SPACING_M))
    return bool(costmap.blocked(points[:n]).any())
