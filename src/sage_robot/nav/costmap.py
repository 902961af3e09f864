"""Costmaps as Nav2 builds them: static, obstacle (mark + ray-trace clear), keepout and
inflation layers, plus a speed-limit layer. Pure numpy/scipy.

Conventions
- Arrays are indexed ``[row, col]``; row 0 is the map origin's y (the bottom), as
  :class:`~sage_robot.core.msgs.OccupancyGrid`. A cell's centre is at
  ``origin + (col + 0.5, row + 0.5) * resolution`` (the map's yaw must be 0).
- Costs are Nav2's ``uint8`` scale: 0 free … 252 inflated, 253 inscribed (the robot's
  centre here means touching), 254 lethal, 255 unknown.
- Inflation (Nav2 ``InflationLayer``): at distance ``d`` from the nearest lethal cell,
  ``d <= inscribed``: 253; ``d <= inflation_radius``: ``252 * exp(-k (d - inscribed))``.
  Unknown blobs smaller than ``SPECKLE_MAX_M2`` inside the map are speckles (free).
  Obstacles seen by the scan (not in the map) are padded, as people's legs need
  (:func:`person_sized`): a small blob (legs, a person) counts ``OBSTACLE_PAD_M`` nearer,
  as a wall; any larger blob (a box, a cart, a wall the map lacks) and scan hits within
  ``WALL_SNAP_M`` of a mapped wall get a *soft* pad: the padded band costs (a little below
  inscribed) but stays passable, so only cells within the inscribed radius of what the robot
  really sees are impassable and no pad ever closes a gap the robot fits through.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from sage_robot.core.msgs import OccupancyGrid

FREE_SPACE = 0
MAX_NON_OBSTACLE = 252
INSCRIBED = 253
LETHAL = 254
NO_INFORMATION = 255
OCCUPIED_MIN = 65  # map cell value (0..100) from which a cell is an obstacle (map_saver's)
OBSTACLE_RANGE_M = 5.0  # Nav2 obstacle_max_range: beams beyond this mark nothing
RAYTRACE_RANGE_M = 6.0  # Nav2 raytrace_max_range: free space is cleared up to here
MARK_BEYOND_CELLS = 0.5  # a beam marks the cell this far (cells) beyond its return
NO_SPEED_LIMIT = 1.0
# Scan obstacles are padded by this much: a lidar at knee height sees a person's legs
# (~0.07 m circles 0.11 m either side of the body's centre), not the 0.25 m body around them.
OBSTACLE_PAD_M = 0.2
# Scan hits this close to a wall of the map are that wall, seen from a pose a few centimetres
# off (localization is never exact). They stay marked (relative to the robot the scan is the
# truest wall there is) with WALL_PAD_M: the legs' 0.2 m boxed in a robot stopped near a
# corner; 0.05 m let paths hug corners so closely that the forward check stopped the robot
# there (dock -> cafe: blocked 4 times in 4); 0.1 m still boxed in at a junction.
WALL_SNAP_M = 0.1
WALL_PAD_M = 0.15  # walls get a thinner pad than legs, and still a margin for the pose error
# The hard core (the inscribed radius) of a hit on a mapped wall is one cell thinner: such a hit
# lands in the free cell before the wall (range noise; the notches of a diagonal wall's cell
# staircase), so every diagonal wall grew a cell and a passage 0.66 m wide (willow-2010's diagonal
# wall, the TurtleBot sandbox) shut for the forward check (issue #20). The map's own wall keeps
# its full inscribed radius; the soft pad still costs.
WALL_CORE_SLACK_CELLS = 1.0
# Scan blobs at most this big (bounding box side, m; marks within BLOB_JOIN_M joined) are
# people or their legs (two 0.07 m legs 0.22 m apart striding 0.14 m; a 0.5 m body's arc) and
# get the hard pad. Larger blobs get the soft pad: the band counts as SOFT_PAD_CLEAR_M beyond
# the inscribed radius (cost ~ 240, passable), never as inscribed.
PERSON_BLOB_M = 0.55
BLOB_JOIN_M = 0.2
SOFT_PAD_CLEAR_M = 0.02
SOFT_PAD_MIN_M = 0.005  # ... rising from this beyond the inscribed radius at the obstacle's edge
SPECKLE_MAX_M2 = 0.5  # unknown blobs smaller than this (m^2) inside the map are noise: free
ATTACHED_M = 0.3  # a small blob this near a wall or a larger blob belongs to it (m)
GAP_MARGIN_M = 0.2  # beside a padded person, a gap keeps at least this much open beyond the robot (m)


@dataclass(frozen=True)
class GridGeometry:
    """Where a grid lies: ``origin_x/y`` (m) of cell (0, 0)'s lower-left corner, ``resolution`` (m)."""

    origin_x: float
    origin_y: float
    resolution: float
    shape: tuple[int, int]  # rows, cols

    @classmethod
    def of(cls, grid: OccupancyGrid) -> GridGeometry:
        if abs(grid.origin.theta) > 1e-6:
            raise ValueError("costmaps need a map whose origin yaw is 0")
        return cls(grid.origin.x, grid.origin.y, grid.resolution, grid.data.shape)

    def to_cell(self, x: np.ndarray | float, y: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """World (m) → (row, col) int arrays; may fall outside the grid."""
        col = np.floor((np.asarray(x, dtype=np.float64) - self.origin_x) / self.resolution).astype(np.int64)
        row = np.floor((np.asarray(y, dtype=np.float64) - self.origin_y) / self.resolution).astype(np.int64)
        return row, col

    def to_world(self, row: np.ndarray | float, col: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """(row, col) → the cell centre in the world (m)."""
        x = self.origin_x + (np.asarray(col, dtype=np.float64) + 0.5) * self.resolution
        y = self.origin_y + (np.asarray(row, dtype=np.float64) + 0.5) * self.resolution
        return x, y

    def inside(self, row: np.ndarray, col: np.ndarray) -> np.ndarray:
        return (row >= 0) & (row < self.shape[0]) & (col >= 0) & (col < self.shape[1])


def edge_distance(edt_cells: np.ndarray, resolution: float) -> np.ndarray:
    """Metres from each cell's centre to the nearest lethal cell's *face* (half a cell less than
    to its centre; 0 on it): the robot's centre at the inscribed radius by this measure does not
    touch the wall, by the centre-to-centre one it could be 2.5 cm into it (the sandbox's
    pillars were scraped at 0.15 m/s with the costmap saying 0.26 m)."""
    out: np.ndarray = np.maximum(edt_cells - 0.5, 0.0).astype(np.float32) * np.float32(resolution)
    return out


def inflate(lethal: np.ndarray, resolution: float, inscribed_m: float, inflation_m: float,
            cost_scaling: float) -> tuple[np.ndarray, np.ndarray]:
    """Nav2 inflation of a boolean lethal mask → (uint8 costs, distance to nearest lethal in m)."""
    if lethal.any():
        dist = edge_distance(ndimage.distance_transform_edt(~lethal).astype(np.float32), resolution)
    else:
        dist = np.full(lethal.shape, np.inf, dtype=np.float32)
    return costs_from_distance(dist, lethal, inscribed_m, inflation_m, cost_scaling), dist


def costs_from_distance(dist: np.ndarray, lethal: np.ndarray, inscribed_m: float, inflation_m: float,
                        cost_scaling: float) -> np.ndarray:
    """Nav2's inflation costs (uint8) of a distance field (m) to the ``lethal`` cells."""
    cost = np.zeros(lethal.shape, dtype=np.uint8)
    ring = (dist > inscribed_m) & (dist <= inflation_m)
    cost[ring] = (MAX_NON_OBSTACLE * np.exp(-cost_scaling * (dist[ring] - inscribed_m))).astype(np.uint8)
    cost[(dist <= inscribed_m) & ~lethal] = INSCRIBED
    cost[lethal] = LETHAL
    return cost


def bounding_box(mask: np.ndarray) -> tuple[int, int, int, int]:
    """First and last row, first and last column of a non-empty 2-D mask. From its rows' and
    columns' ``any`` (0.1 ms on a 2000 x 1600 map), not ``np.nonzero`` (25 ms there)."""
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    return int(rows[0]), int(rows[-1]), int(cols[0]), int(cols[-1])


def drop_speckles(unknown: np.ndarray, resolution: float) -> np.ndarray:
    """``unknown`` without its speckles: blobs of unknown cells smaller than ``SPECKLE_MAX_M2``
    that do not touch the grid's edge are map noise in free space (a SLAM map's unseen pixels
    between two scans), not unexplored space; left unknown they stop the forward check."""
    if not unknown.any():
        return unknown
    labels, n = ndimage.label(unknown, structure=np.ones((3, 3)))
    sizes = np.bincount(labels.ravel(), minlength=n + 1) * resolution * resolution
    edge = np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]]))
    speck = sizes < SPECKLE_MAX_M2
    speck[edge] = False
    speck[0] = False
    out: np.ndarray = unknown & ~speck[labels]
    return out


def person_sized(marks: np.ndarray, resolution: float, walls: np.ndarray | None = None) -> np.ndarray:
    """The marks that belong to free-standing blobs no bigger than a person (``PERSON_BLOB_M``),
    marks within ``BLOB_JOIN_M`` of each other joined (a person's two legs are one blob). A blob
    that joins one of ``walls`` (the map's walls, scan hits on them) is part of that wall (a
    box or a cabinet against it), never a person."""
    if not marks.any():
        return np.zeros(marks.shape, dtype=bool)
    join = max(1, round(BLOB_JOIN_M / resolution / 2))
    disk = np.hypot(*np.mgrid[-join:join + 1, -join:join + 1]) <= join
    every = marks if walls is None else marks | walls
    labels, n = ndimage.label(ndimage.binary_dilation(every, structure=disk), structure=np.ones((3, 3)))
    small = np.zeros(n + 1, dtype=bool)
    for i, sl in enumerate(ndimage.find_objects(labels), start=1):
        if sl is None:
            continue
        side = max(sl[0].stop - sl[0].start, sl[1].stop - sl[1].start) - 2 * join
        small[i] = side * resolution <= PERSON_BLOB_M
    if walls is not None:
        small[np.unique(labels[walls])] = False
        small[0] = False
    out: np.ndarray = small[labels] & marks
    # a small blob this near a wall or a larger blob is a piece of it (a face the lidar sees at a
    # grazing angle comes in sparse points), not a person
    rest = (marks & ~out) if walls is None else (marks & ~out) | walls
    if out.any() and rest.any():
        near = ndimage.distance_transform_edt(~rest) * resolution <= ATTACHED_M
        attached = np.zeros(n + 1, dtype=bool)
        attached[np.unique(labels[out & near])] = True
        out &= ~attached[labels]
    return out


def resample_mask(mask: OccupancyGrid, geom: GridGeometry, fill: int = -1) -> np.ndarray:
    """A Nav2 filter mask read onto ``geom``'s cells (nearest cell; outside → ``fill``)."""
    rows, cols = np.indices(geom.shape)
    x, y = geom.to_world(rows, cols)
    mg = GridGeometry.of(mask)
    r, c = mg.to_cell(x, y)
    ok = mg.inside(r, c)
    out = np.full(geom.shape, fill, dtype=np.int16)
    out[ok] = mask.data[r[ok], c[ok]]
    return out


def speed_limits_from_mask(values: np.ndarray) -> np.ndarray:
    """Nav2 SpeedFilter, percentage type (base 0, multiplier 1): a mask value v in 1..100 limits
    the speed to v % of the maximum; 0 and unknown (-1) mean no limit. → fraction 0..1."""
    frac = np.full(values.shape, NO_SPEED_LIMIT, dtype=np.float32)
    limited = (values > 0) & (values <= 100)
    frac[limited] = values[limited] / 100.0
    return frac


class Costmap:
    """A layered costmap over one grid.

    Layers: ``static`` (walls from the map), ``obstacles`` (marked from scans, cleared by
    ray tracing), ``keepout`` (never enter). ``cost`` is the combined, inflated uint8 grid;
    ``dist`` the distance (m) to the nearest lethal cell; ``speed`` the speed-limit fraction.
    """

    def __init__(self, geom: GridGeometry, static: np.ndarray, unknown: np.ndarray,
                 inscribed_m: float, inflation_m: float, cost_scaling: float,
                 keepout: np.ndarray | None = None, speed: np.ndarray | None = None,
                 derived: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> None:
        """``derived``: the wall zone, the inflated cost of the walls and keep-out (before the
        unknown cells are marked) and the distance to them, when already known (a window cut
        from a larger costmap); computed here otherwise."""
        self.geom = geom
        self.inscribed_m, self.inflation_m, self.cost_scaling = inscribed_m, inflation_m, cost_scaling
        self.static = static.astype(bool)
        unknown = unknown.astype(bool)
        self.unknown = drop_speckles(unknown, geom.resolution) if unknown.any() else unknown
        self.keepout = np.zeros(geom.shape, bool) if keepout is None else keepout.astype(bool)
        self.speed = np.full(geom.shape, NO_SPEED_LIMIT, np.float32) if speed is None else speed
        self.obstacles = np.zeros(geom.shape, dtype=bool)
        if derived is None:
            snap = max(1, round(WALL_SNAP_M / geom.resolution))
            disk = np.hypot(*np.mgrid[-snap:snap + 1, -snap:snap + 1]) <= snap
            wall_zone = ndimage.binary_dilation(self.static, structure=disk)
            wall_cost, wall_dist = inflate(self.static | self.keepout, geom.resolution, inscribed_m,
                                           inflation_m, cost_scaling)
        else:
            wall_zone, wall_cost, wall_dist = derived
        self.wall_zone = wall_zone  # scan hits here are walls
        self._wall_cost, self._base_dist = wall_cost, wall_dist
        self._base_cost = wall_cost.copy()
        self._base_cost[self.unknown & (self._base_cost < LETHAL)] = NO_INFORMATION
        self.cost = self._base_cost.copy()
        self.dist = self._base_dist.copy()
        self._dirty: tuple[slice, slice] | None = None  # where cost and dist differ from the base

    # ------------------------------------------------------------------ building
    @classmethod
    def from_grid(cls, grid: OccupancyGrid, inscribed_m: float, inflation_m: float,
                  cost_scaling: float, keepout_mask: OccupancyGrid | None = None,
                  speed_mask: OccupancyGrid | None = None) -> Costmap:
        geom = GridGeometry.of(grid)
        static = grid.data >= OCCUPIED_MIN
        unknown = grid.data < 0
        keepout = None
        if keepout_mask is not None:
            k = resample_mask(keepout_mask, geom, fill=0)
            keepout = k >= OCCUPIED_MIN
        speed = None
        if speed_mask is not None:
            speed = speed_limits_from_mask(resample_mask(speed_mask, geom, fill=-1))
        return cls(geom, static, unknown, inscribed_m, inflation_m, cost_scaling, keepout, speed)

    def window(self, cx: float, cy: float, size_m: float) -> Costmap:
        """A rolling local costmap: the square of side ``size_m`` centred on (cx, cy), static and
        keepout layers copied, obstacle layer empty (the local costmap marks only live scans).
        As Nav2's rolling local costmap (``track_unknown_space: false``) it does not keep the
        map's unknown cells, only what lies outside the map: the planner keeps out of unknown
        space, and the forward check must not stop the robot beside a patch of it (issue #20:
        on a real SLAM map, unseen patches beside the path stopped it for good)."""
        g, n = self.geom, max(3, round(size_m / self.geom.resolution))
        rc = g.to_cell(cx - size_m / 2, cy - size_m / 2)
        r0, c0 = int(rc[0]), int(rc[1])
        geom = GridGeometry(g.origin_x + c0 * g.resolution, g.origin_y + r0 * g.resolution,
                            g.resolution, (n, n))

        def cut(a: np.ndarray, fill: float) -> np.ndarray:
            out = np.full((n, n), fill, dtype=a.dtype)
            rs, cs = slice(max(r0, 0), min(r0 + n, g.shape[0])), slice(max(c0, 0), min(c0 + n, g.shape[1]))
            if rs.start < rs.stop and cs.start < cs.stop:
                out[rs.start - r0:rs.stop - r0, cs.start - c0:cs.stop - c0] = a[rs, cs]
            return out

        if r0 >= 0 and c0 >= 0 and r0 + n <= g.shape[0] and c0 + n <= g.shape[1]:
            # inside the map (nearly always): the walls' zone and inflation are cut from this
            # costmap's, not computed again for every scan (they also see walls just outside the
            # window, as the window's own would not)
            rs, cs = slice(r0, r0 + n), slice(c0, c0 + n)
            derived = (self.wall_zone[rs, cs].copy(), self._wall_cost[rs, cs].copy(),
                       self._base_dist[rs, cs].copy())
            return Costmap(geom, self.static[rs, cs], np.zeros((n, n), dtype=bool), self.inscribed_m,
                           self.inflation_m, self.cost_scaling, self.keepout[rs, cs],
                           self.speed[rs, cs].copy(), derived)
        outside = np.ones((n, n), dtype=bool)
        rs, cs = slice(max(r0, 0), min(r0 + n, g.shape[0])), slice(max(c0, 0), min(c0 + n, g.shape[1]))
        if rs.start < rs.stop and cs.start < cs.stop:
            outside[rs.start - r0:rs.stop - r0, cs.start - c0:cs.stop - c0] = False
        return Costmap(geom, cut(self.static, True), outside, self.inscribed_m,
                       self.inflation_m, self.cost_scaling, cut(self.keepout, False),
                       cut(self.speed, NO_SPEED_LIMIT))

    # ------------------------------------------------------------------ obstacle layer
    def update_scan(self, sensor_pose: tuple[float, float, float], angles: np.ndarray,
                    ranges: np.ndarray, range_max: float, forget_beyond_m: float | None = None) -> None:
        """Clear cells along each beam (up to RAYTRACE_RANGE_M), then mark the hit cells of beams
        shorter than OBSTACLE_RANGE_M. ``sensor_pose`` is the lidar's (x, y, yaw) in this map's
        frame; ``angles`` (rad, sensor frame) and ``ranges`` (m; inf = no return)."""
        sx, sy, st = sensor_pose
        r = np.asarray(ranges, dtype=np.float64)
        finite = np.isfinite(r) & (r > 0)
        clear_len = np.where(finite, np.minimum(r, RAYTRACE_RANGE_M), min(range_max, RAYTRACE_RANGE_M))
        a = np.asarray(angles, dtype=np.float64) + st
        ca, sa = np.cos(a), np.sin(a)
        step = self.geom.resolution * 0.5
        n_steps = math.ceil(clear_len.max() / step) if len(clear_len) else 0
        if n_steps:
            t = np.arange(n_steps) * step
            # stop one cell short of the hit so the wall itself is never cleared
            keep = t[None, :] < (clear_len[:, None] - self.geom.resolution)
            px = sx + ca[:, None] * t[None, :]
            py = sy + sa[:, None] * t[None, :]
            rows, cols = self.geom.to_cell(px[keep], py[keep])
            ok = self.geom.inside(rows, cols)
            self.obstacles[rows[ok], cols[ok]] = False
        mark = finite & (r < OBSTACLE_RANGE_M)
        # a return comes from the obstacle's surface: the cell that holds the obstacle is the one
        # just beyond it (the endpoint's own cell is, half the time, the free cell in front of a
        # wall: every wall grew a cell toward the robot, and a 0.56 m gap shut; issue #20)
        hit = r[mark] + MARK_BEYOND_CELLS * self.geom.resolution
        hr, hc = self.geom.to_cell(sx + ca[mark] * hit, sy + sa[mark] * hit)
        ok = self.geom.inside(hr, hc)
        self.obstacles[hr[ok], hc[ok]] = True
        self.obstacles &= ~self.static  # walls belong to the static layer
        if forget_beyond_m is not None:
            self._forget_outside(sx, sy, forget_beyond_m)
        self.refresh()

    def _forget_outside(self, x: float, y: float, radius_m: float) -> None:
        """Drop scan marks outside the square of half-side ``radius_m`` around (x, y), so the
        re-inflated region stays small on a large map (marks far away are stale anyway)."""
        g = self.geom
        lo, hi = g.to_cell(x - radius_m, y - radius_m), g.to_cell(x + radius_m, y + radius_m)
        r0, c0 = max(int(lo[0]), 0), max(int(lo[1]), 0)
        r1, c1 = min(int(hi[0]) + 1, g.shape[0]), min(int(hi[1]) + 1, g.shape[1])
        keep = self.obstacles[r0:r1, c0:c1].copy()
        self.obstacles[:] = False
        self.obstacles[r0:r1, c0:c1] = keep

    def clear_obstacles_near(self, x: float, y: float, radius_m: float) -> None:
        """Forget the scan marks within the square of half-side ``radius_m`` around (x, y)."""
        g = self.geom
        lo, hi = g.to_cell(x - radius_m, y - radius_m), g.to_cell(x + radius_m, y + radius_m)
        r0, c0 = max(int(lo[0]), 0), max(int(lo[1]), 0)
        self.obstacles[r0:max(int(hi[0]) + 1, 0), c0:max(int(hi[1]) + 1, 0)] = False
        self.refresh()

    @contextlib.contextmanager
    def impassable_as(self, local: Costmap | None) -> Iterator[None]:
        """For the block's duration, the cells ``local`` (the controller's rolling window, cut
        from this costmap's grid) finds impassable are impassable here too, so a plan does not
        run where the controller will stop. The two can disagree: the pad of what the scan marks
        depends on the marks around it, and this costmap remembers more of them than the live
        window (issue #20, willow-2010: a box's impassable zone reached two cells further in
        the window than here, where the robot stood stopped beside it)."""
        if local is None:
            yield
            return
        rr, cc = np.nonzero((local.cost >= INSCRIBED) & (local.cost != NO_INFORMATION))
        xs, ys = local.geom.to_world(rr, cc)
        r, c = self.geom.to_cell(xs, ys)
        ok = self.geom.inside(r, c)
        r, c = r[ok], c[ok]
        free = self.cost[r, c] < INSCRIBED
        r, c = r[free], c[free]
        saved = self.cost[r, c].copy()
        self.cost[r, c] = INSCRIBED
        try:
            yield
        finally:
            self.cost[r, c] = saved

    def clear_obstacles(self) -> None:
        """Nav2's clear-costmap recovery: forget everything the scans marked."""
        self.obstacles[:] = False
        self.refresh()

    def refresh(self) -> None:
        """Recombine the layers. Only the bounding box of the obstacles (plus the inflation
        radius) is re-inflated, and only the box the last refresh changed is reset to the walls'
        layers, in place: a large map with a few people costs little (two full copies of the
        campus map's layers took 2-3 ms of every refresh)."""
        if self._dirty is not None:
            rs, cs = self._dirty
            self.cost[rs, cs] = self._base_cost[rs, cs]
            self.dist[rs, cs] = self._base_dist[rs, cs]
            self._dirty = None
        if not self.obstacles.any():
            return
        rmin, rmax, cmin, cmax = bounding_box(self.obstacles)
        margin = math.ceil((self.inflation_m + OBSTACLE_PAD_M) / self.geom.resolution) + 1  # cells
        r0, r1 = max(rmin - margin, 0), min(rmax + margin + 1, self.geom.shape[0])
        c0, c1 = max(cmin - margin, 0), min(cmax + margin + 1, self.geom.shape[1])
        self._dirty = (slice(r0, r1), slice(c0, c1))
        lethal, wall = self.obstacles[r0:r1, c0:c1], self.wall_zone[r0:r1, c0:c1]
        people = person_sized(lethal & ~wall, self.geom.resolution,
                              self.static[r0:r1, c0:c1] | (lethal & wall))
        layers = ((people, OBSTACLE_PAD_M, True, 0.0), (lethal & ~wall & ~people, OBSTACLE_PAD_M, False, 0.0),
                  (lethal & wall, WALL_PAD_M, False, WALL_CORE_SLACK_CELLS * self.geom.resolution))
        for marks, pad, hard, slack in layers:
            if not marks.any():
                continue
            raw = edge_distance(ndimage.distance_transform_edt(~marks), self.geom.resolution)
            if hard:  # people: the full pad, except where it would close a gap the robot fits
                others = lethal | self.static[r0:r1, c0:c1] | self.keepout[r0:r1, c0:c1]
                dist = self._capped_pad(marks, others, raw, pad)
            else:  # the pad costs, but never makes a cell the robot fits in impassable
                dist = np.maximum(raw - pad, self._soft(raw, pad, slack))
            cost = costs_from_distance(dist, marks, self.inscribed_m, self.inflation_m, self.cost_scaling)
            self.cost[r0:r1, c0:c1] = np.maximum(self.cost[r0:r1, c0:c1], cost)
            self.dist[r0:r1, c0:c1] = np.minimum(self.dist[r0:r1, c0:c1], dist)

    def _soft(self, raw: np.ndarray, pad: float, slack: float) -> np.ndarray:
        """The distance a soft pad reports: inside the inscribed radius (less ``slack``) the true
        one; across the padded band from just beyond the inscribed radius up to
        ``SOFT_PAD_CLEAR_M`` beyond it, rising with the true distance, so the band costs (a little
        below inscribed) and the planner still keeps to the middle of a gap (a flat band let
        paths hug one side of a narrow passage, and the forward check stopped the robot there)."""
        ins = self.inscribed_m
        slope = (SOFT_PAD_CLEAR_M - SOFT_PAD_MIN_M) / (pad + SOFT_PAD_CLEAR_M)
        rise = np.clip(raw - ins, 0.0, None) * slope
        out: np.ndarray = np.where(raw + slack <= ins, raw + slack, ins + SOFT_PAD_MIN_M + rise)
        return out

    def _capped_pad(self, people: np.ndarray, others: np.ndarray, raw: np.ndarray, pad: float) -> np.ndarray:
        """Distance (m) to the ``people`` marks padded by ``pad``, blob by blob, the pad cut where
        it would close a gap: between a blob and anything else (``others``: every lethal cell) a
        gap of width ``w`` keeps ``w - 2 inscribed - GAP_MARGIN_M`` open, shared by both sides."""
        res = self.geom.resolution
        out = np.maximum(raw - pad, 0.0)
        join = max(1, round(BLOB_JOIN_M / res / 2))
        disk = np.hypot(*np.mgrid[-join:join + 1, -join:join + 1]) <= join
        labels, _n = ndimage.label(ndimage.binary_dilation(people, structure=disk), structure=np.ones((3, 3)))
        m = math.ceil((2 * self.inscribed_m + 2 * pad + GAP_MARGIN_M) / res) + 1
        for i, sl in enumerate(ndimage.find_objects(labels), start=1):
            if sl is None:
                continue
            rs = slice(max(sl[0].start - m, 0), min(sl[0].stop + m, people.shape[0]))
            cs = slice(max(sl[1].start - m, 0), min(sl[1].stop + m, people.shape[1]))
            blob = people[rs, cs] & (labels[rs, cs] == i)
            rest = others[rs, cs] & ~blob
            if not rest.any():
                continue
            near = edge_distance(ndimage.distance_transform_edt(~blob), res)
            far = edge_distance(ndimage.distance_transform_edt(~rest), res)
            cap = np.clip((near + far - 2 * self.inscribed_m - GAP_MARGIN_M) / 2, 0.0, pad)
            band = (near <= raw[rs, cs] + 1e-3) & (cap < pad)  # cells this blob is the nearest to
            sub = out[rs, cs]
            sub[band] = np.maximum(sub[band], near[band] - cap[band])
        return out

    # ------------------------------------------------------------------ queries
    def cost_at(self, x: np.ndarray | float, y: np.ndarray | float) -> np.ndarray:
        """Cost at world points; outside the grid is NO_INFORMATION."""
        r, c = self.geom.to_cell(x, y)
        ok = self.geom.inside(r, c)
        out = np.full(np.shape(r), NO_INFORMATION, dtype=np.uint8)
        out[ok] = self.cost[r[ok], c[ok]]
        return out

    def distance_at(self, x: float, y: float) -> float:
        """Distance (m) from a point to the nearest lethal cell (0 outside the grid)."""
        r, c = self.geom.to_cell(x, y)
        if not bool(self.geom.inside(r, c)):
            return 0.0
        return float(self.dist[int(r), int(c)])

    def wall_distance(self, xy: np.ndarray) -> np.ndarray:
        """Distance (m) from (N, 2) points to the map's walls (static and keepout, no scan marks)."""
        r, c = self.geom.to_cell(xy[:, 0], xy[:, 1])
        ok = self.geom.inside(r, c)
        out = np.zeros(len(xy), dtype=np.float32)  # outside the grid counts as a wall
        out[ok] = self._base_dist[r[ok], c[ok]]
        return out

    def speed_limit_at(self, x: float, y: float) -> float:
        """Speed-limit fraction (0..1] at a point; 1 = no limit."""
        r, c = self.geom.to_cell(x, y)
        if not bool(self.geom.inside(r, c)):
            return NO_SPEED_LIMIT
        return float(self.speed[int(r), int(c)])

    def blocked(self, xy: np.ndarray) -> np.ndarray:
        """Which (N, 2) points put the robot in collision (inscribed, lethal or unknown)."""
        if len(xy) == 0:
            return np.zeros(0, dtype=bool)
        return self.cost_at(xy[:, 0], xy[:, 1]) >= INSCRIBED
