"""The ``jupedsim`` crowd backend: the simulated people moved by JuPedSim.

JuPedSim (https://www.jupedsim.org, LGPL-3.0, the optional extra ``people``) steps every
person with its collision-free speed model (Tordeux et al. 2016) on the walkable floor:
the map's free cells connected to the robot's start, as one polygon (holes for pillars
and furniture in the map). People keep clear of walls and of each other, pass in
counter-flow, queue in doorways. The robot is an agent of its own that JuPedSim steers to
the robot's true pose every step, so people avoid it as they avoid each other; on top, a
person whose next step could reach the robot's body stands still for that step, so nobody
ever stands inside the robot.

Where people go is decided as in the ``simple`` backend (lanes, standing, the approacher,
stepping aside when asked: :class:`~sage_robot.sim.people.Crowd` is the base class); each
goal is reached by JuPedSim's routing on the walkable polygon (around corners), and the
model does the walking. Deterministic: the same inputs give the same steps, and JuPedSim
advances in fixed ``JPS_STEP_S`` ticks of the simulator's time.
"""

from __future__ import annotations

import math
from typing import Any

import jupedsim as jps
import numpy as np
import shapely
import shapely.ops
from scipy import ndimage

from sage_robot.core.mapio import FREE, world_to_cell
from sage_robot.core.msgs import OccupancyGrid
from sage_robot.sim.people import (
    ARRIVE_M,
    HELD_UP_M,
    PERSON_RADIUS_M,
    ROBOT_GAP_M,
    STRIDE_RATE,
    TURN_BACK_S,
    Crowd,
    Lanes,
    PersonState,
)

JPS_STEP_S = 0.01  # JuPedSim's fixed time step (s); the world's dt is spent in these ticks
ROBOT_AGENT_MPS = 5.0  # the robot's agent may move this fast to keep up with the true pose
CORNER_M = 0.3  # a routed corner counts as passed this close (m)
GUARD_STEPS = 3  # a person within this many of their steps of the robot's body waits
STUCK_S = 6.0  # a person with a goal who has not got STUCK_M anywhere for this long gives it up
STUCK_M = 0.1  # ... measured from where they stood: JuPedSim's agents can jitter in place, a few
# millimetres to and fro every tick, wedged between a pillar, others and the robot (measured on
# the TurtleBot sandbox: four people 200 s in one spot at 0.2-1.2 m/s a tick), so the speed of
# one tick does not say that someone gets anywhere
PART_RINGS_CELLS = 0.25  # the walkable polygon is widened by this many cells (see below)
MIN_HOLE_M2 = 0.05  # holes in the walkable polygon smaller than this are dropped (specks)
SIMPLIFY_M = 0.05  # the walkable polygon is simplified to this tolerance
NUDGE_M = (0.1, 0.2, 0.3, 0.45, 0.6)  # a person placed on another is moved this far...
NUDGE_DIRECTIONS = 8  # ...in one of these directions (the first that fits)
INSIDE_M = 0.05  # the robot's agent is sent this far inside the polygon when the robot is off it


def walkable_polygon(grid: OccupancyGrid, start: tuple[float, float]) -> Any:
    """The free cells 4-connected to ``start`` as one shapely Polygon (m, map frame;
    an unrotated map origin), simplified to SIMPLIFY_M."""
    if abs(grid.origin.theta) > 1e-9:
        raise ValueError("the jupedsim people model needs a map with an unrotated origin")
    labels, _ = ndimage.label(grid.data == FREE)
    r, c = world_to_cell(grid, start[0], start[1])
    row, col = int(r), int(c)
    if not (0 <= row < grid.height and 0 <= col < grid.width) or labels[row, col] == 0:
        raise ValueError(f"the start ({start[0]:.2f}, {start[1]:.2f}) is not on free floor")
    mask = labels == labels[row, col]
    res, ox, oy = grid.resolution, grid.origin.x, grid.origin.y
    boxes = [
        shapely.box(ox + c0 * res, oy + r0 * res, ox + c1 * res, oy + r1 * res)
        for (c0, c1), r0, r1 in _row_runs(mask)
    ]
    union = shapely.unary_union(boxes)
    parts = list(union.geoms) if hasattr(union, "geoms") else [union]
    here = shapely.Point(start[0], start[1])
    poly = next((p for p in parts if p.covers(here)), max(parts, key=lambda p: p.area))
    # JuPedSim's triangulation crashes (a segfault, measured on willow-2010-02-18) on rings
    # that touch at a point (diagonal cells): widening the floor by a fraction of a cell
    # parts them; then simplify (SIMPLIFY_M) and drop specks (a finer polygon made its geometry
    # and routing take 53 s to build on willow-full instead of 5 s, measured).
    poly = poly.buffer(res * PART_RINGS_CELLS, join_style="mitre")
    poly = poly.simplify(SIMPLIFY_M, preserve_topology=True)
    holes = [h for h in poly.interiors if shapely.Polygon(h).area >= MIN_HOLE_M2]
    return shapely.Polygon(poly.exterior, holes)


def _row_runs(mask: np.ndarray) -> list[tuple[tuple[int, int], int, int]]:
    """Rectangles covering ``mask``: runs of True cells in a row, merged with the identical
    runs of the rows above: ((col0, col1), row0, row1), ends exclusive."""
    out: list[tuple[tuple[int, int], int, int]] = []
    open_runs: dict[tuple[int, int], int] = {}
    for row in range(mask.shape[0]):
        edges = np.flatnonzero(np.diff(np.concatenate(([0], mask[row].astype(np.int8), [0]))))
        runs = {(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)}
        for run in [r for r in open_runs if r not in runs]:
            out.append((run, open_runs.pop(run), row))
        for run in sorted(runs):
            open_runs.setdefault(run, row)
    out += [(run, r0, mask.shape[0]) for run, r0 in sorted(open_runs.items())]
    return out


class JpsCrowd(Crowd):
    """Every simulated person as a JuPedSim agent (collision-free speed model)."""

    def __init__(
        self,
        people: list[PersonState],
        lanes: Lanes | None,
        clearance: Any,
        rng: np.random.Generator,
        line_of_sight: Any = None,
        *,
        grid: OccupancyGrid,
        start: tuple[float, float, float],
        robot_radius: float,
    ) -> None:
        super().__init__(people, lanes, clearance, rng, line_of_sight)
        self.polygon = walkable_polygon(grid, start[:2])
        self._sim = jps.Simulation(model=jps.CollisionFreeSpeedModel(), geometry=self.polygon, dt=JPS_STEP_S)
        self._routing = jps.RoutingEngine(self.polygon)
        stage = self._sim.add_direct_steering_stage()
        self._journey = self._sim.add_journey(jps.JourneyDescription([stage]))
        self._stage = stage
        self._robot_agent = self._add((start[0], start[1]), robot_radius, 0.0, "the robot's start")
        self._agents = [self._place(p) for p in self.people]
        self._routes: dict[int, tuple[tuple[float, float], list[tuple[float, float]]]] = {}
        self._still_s = [0.0] * len(self.people)
        self._anchor = [(p.x, p.y) for p in self.people]  # where each one stood when last counted moving
        self._owed_s = 0.0  # simulated time not yet spent in JuPedSim ticks
        self._inner: Any = None  # the polygon shrunk by INSIDE_M, made when first needed

    def _add(self, xy: tuple[float, float], radius: float, speed: float, what: str) -> int:
        params = jps.CollisionFreeSpeedModelAgentParameters(
            position=xy, radius=radius, desired_speed=speed, journey_id=self._journey, stage_id=self._stage
        )
        try:
            agent = int(self._sim.add_agent(params))
        except RuntimeError as exc:
            raise ValueError(
                f"{what} ({xy[0]:.2f}, {xy[1]:.2f}) does not fit on the walkable floor: {exc}"
            ) from None
        self._sim.agent(agent).target = xy
        return agent

    def _place(self, p: PersonState) -> int:
        """Add ``p`` where it stands, or nudged to the nearest spot that fits (people the
        simple spawner put on top of each other)."""
        turns = [2 * math.pi * k / NUDGE_DIRECTIONS for k in range(NUDGE_DIRECTIONS)]
        tries = [(0.0, 0.0)] + [(d * math.cos(a), d * math.sin(a)) for d in NUDGE_M for a in turns]
        error = ValueError(f"person {p.id} does not fit")
        for dx, dy in tries:
            try:
                agent = self._add((p.x + dx, p.y + dy), PERSON_RADIUS_M, p.speed_mps, f"person {p.id}")
            except ValueError as exc:
                error = exc
                continue
            p.x, p.y = p.x + dx, p.y + dy
            return agent
        raise error

    # ---------------------------------------------------------------- stepping
    def step(self, dt: float, t: float, robot: tuple[float, float, float], robot_radius: float) -> None:
        self._owed_s += dt
        while self._owed_s >= JPS_STEP_S - 1e-12:
            self._owed_s -= JPS_STEP_S
            self._tick(t, robot, robot_radius)
            t += JPS_STEP_S

    def _tick(self, t: float, robot: tuple[float, float, float], rr: float) -> None:
        goals = []
        for i, p in enumerate(self.people):
            goal = self._reachable(p, self._goal(p, t, robot))
            goals.append(goal)
            agent = self._sim.agent(self._agents[i])
            if goal is None:
                agent.target, agent.model.desired_speed = (p.x, p.y), 0.0
                if p.behaviour == "approacher" and p.stay_until > t:
                    p.theta = math.atan2(robot[1] - p.y, robot[0] - p.x)
                continue
            corner = self._corner(p, goal)
            agent.target = corner
            agent.model.desired_speed = 0.0 if self._guarded(p, corner, robot, rr) else p.speed_mps
        me = self._sim.agent(self._robot_agent)
        me.target = self._robot_target(robot)
        me.model.desired_speed = ROBOT_AGENT_MPS
        self._sim.iterate()
        for i, p in enumerate(self.people):
            self._read_back(i, p, goals[i], robot, rr)

    def _robot_target(self, robot: tuple[float, float, float]) -> tuple[float, float]:
        """Where the robot's agent heads: the robot's true position, or the nearest point well
        inside the walkable polygon when the robot is outside it (close to a wall the polygon's
        simplification cut off, or on floor JuPedSim's people do not reach): JuPedSim refuses a
        target outside its accessible area (measured on willow: the world crashed there)."""
        xy = (robot[0], robot[1])
        if self._routing.is_routable(xy):
            return xy
        if self._inner is None:
            self._inner = self.polygon.buffer(-INSIDE_M)
        if self._inner.is_empty:
            return (float(self._sim.agent(self._robot_agent).position[0]),
                    float(self._sim.agent(self._robot_agent).position[1]))
        q = shapely.ops.nearest_points(self._inner, shapely.Point(xy))[0]
        return (float(q.x), float(q.y))

    def _reachable(self, p: PersonState, goal: tuple[float, float] | None) -> tuple[float, float] | None:
        """``goal``, or None (and the goal dropped) when it is off the walkable polygon (a
        random spot or lane node in a part of the map the robot's floor does not reach)."""
        if goal is None or self._routing.is_routable(goal):
            return goal
        if p.aside:
            p.aside.clear()
        elif p.route:
            p.route.pop(0)
        return None

    def _guarded(self, p: PersonState, corner: tuple[float, float], robot: tuple[float, float, float],
                 rr: float) -> bool:
        """True when this tick's step could bring ``p`` into the robot's body (+ gap):
        close to it and heading its way."""
        rx, ry = robot[0] - p.x, robot[1] - p.y
        gap = math.hypot(rx, ry) - (PERSON_RADIUS_M + rr + ROBOT_GAP_M)
        if gap > GUARD_STEPS * p.speed_mps * JPS_STEP_S:
            return False
        return (corner[0] - p.x) * rx + (corner[1] - p.y) * ry > 0.0

    def _corner(self, p: PersonState, goal: tuple[float, float]) -> tuple[float, float]:
        """The next corner of the routed way to ``goal`` (straight when in sight)."""
        cached = self._routes.get(p.id)
        if cached is None or cached[0] != goal:
            try:
                way = [(float(w[0]), float(w[1])) for w in self._routing.compute_waypoints((p.x, p.y), goal)]
            except RuntimeError:
                way = [goal]
            # a corner of the way can lie on the floor's edge, where JuPedSim refuses it as a
            # target (its step failed on willow-2010): such corners are skipped
            cached = (goal, [w for w in way[1:] if self._routing.is_routable(w)] or [goal])
            self._routes[p.id] = cached
        way = cached[1]
        while len(way) > 1 and math.hypot(way[0][0] - p.x, way[0][1] - p.y) < CORNER_M:
            way.pop(0)
        return way[0]

    def _read_back(self, i: int, p: PersonState, goal: tuple[float, float] | None,
                   robot: tuple[float, float, float], rr: float) -> None:
        agent = self._sim.agent(self._agents[i])
        x, y = (float(v) for v in agent.position)
        moved = math.hypot(x - p.x, y - p.y)
        if moved > 1e-9:
            p.theta = math.atan2(y - p.y, x - p.x)
        p.x, p.y = x, y
        p.moving = moved / JPS_STEP_S
        p.phase = (p.phase + STRIDE_RATE * moved) % (2 * math.pi)
        ax, ay = self._anchor[i]
        if goal is None or math.hypot(x - ax, y - ay) >= STUCK_M:
            self._anchor[i] = (x, y)
            self._still_s[i] = 0.0
            p.waited_s = 0.0
            return
        self._still_s[i] += JPS_STEP_S
        if math.hypot(robot[0] - x, robot[1] - y) < PERSON_RADIUS_M + rr + ROBOT_GAP_M + HELD_UP_M:
            p.waited_s += JPS_STEP_S  # held up at the robot, as in the simple model
            if p.waited_s >= TURN_BACK_S:
                self._turn_back(p, robot)
                self._still_s[i] = 0.0
            return
        if self._still_s[i] >= STUCK_S:  # wedged (a crowd, a corner): give this goal up
            self._still_s[i] = 0.0
            if p.aside:
                p.aside.clear()
            elif p.route and math.hypot(p.route[0][0] - x, p.route[0][1] - y) >= ARRIVE_M:
                p.route.pop(0)
