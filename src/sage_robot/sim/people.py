"""Simulated pedestrians: walkers along corridors, people who stop and stand, small groups
standing or walking together, and someone who walks up to the robot and stays a while.

Pure (numpy + stdlib): every random choice comes from the ``numpy.random.Generator``
given, so a seed gives the same crowd and the same walk. Map frame, metres, radians.

People see the robot: a walker steps aside when the robot is ahead of it, walks around a
robot that stands still (keeping its distance) and otherwise waits rather than walk into
it, so every contact between the two is the robot's doing. A walker on the lanes held up
at the robot for ``TURN_BACK_S`` (waiting, or circling it without getting by: the robot
fills a doorway) turns back the way it came, as people do; scenario patrols keep waiting.
People do not avoid each other (the lidar sees them all the same).
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sage_robot.sim import walking_group

PERSON_RADIUS_M = 0.25  # body circle for collisions and the camera
LEG_RADIUS_M = 0.07  # each leg, as the lidar sees it at ~0.5 m height
LEG_HALF_SPACING_M = 0.11  # legs sit this far left/right of the body centre
STRIDE_M = 0.14  # legs swing this far forward/back while walking
STRIDE_RATE = 4.0  # leg phase (rad) per metre walked
WALK_SPEED_MPS = (0.8, 1.3)  # walkers pick a speed in this range
APPROACH_SPEED_MPS = 0.9
ROBOT_GAP_M = 0.15  # a person never moves closer than this to the robot's body
AVOID_LOOKAHEAD_M = 1.5  # a walker steps aside when the robot is this close ahead
SIDESTEP_MPS = 0.5
ROBOT_HALTED_MPS = 0.05  # a walker goes around a robot slower than this instead of waiting
TURN_BACK_S = 10.0  # a walker held up this long at a robot (no room to pass) turns back
HELD_UP_M = 0.5  # ... held up: within this of the gap it keeps from the robot
STAND_S = (4.0, 15.0)  # a walker who stops stands this long
STOP_PROBABILITY = 0.15  # chance a walker stops at each waypoint
APPROACH_STOP_M = 1.0  # the approacher stops this far from the robot's centre
APPROACH_DELAY_S = (3.0, 15.0)
APPROACH_MAX_ROBOT_MPS = 0.2  # the approacher only walks up to a robot slower than this
APPROACH_STAY_S = (30.0, 60.0)
WALL_MARGIN_M = 0.05  # people keep their body this far clear of walls
ARRIVE_M = 0.15
SPAWN_MIN_DIST_M = 5.0  # random people start at least this far from the robot
EDGE_TRIES = 50
RANDOM_SPOT_M = 8.0  # on a map without lanes people walk to random spots this far (x and y)
ROOMY_M = 0.3  # ... with this much room around their body
WAITING_MPS = 0.05  # a person slower than this is standing (a leader does not wait for them)
WALKING = ("walker", "companion")  # people who step aside from the robot's way and walk around it
CORRIDOR_HALF_MIN_M = 0.8  # lane edges at least this half-wide are corridors (spurs are narrower)


@dataclass
class PersonState:
    """A person's mutable state (the ``Person`` message is its snapshot)."""

    id: int
    x: float
    y: float
    theta: float = 0.0
    behaviour: str = "walker"  # walker | stander | group | approacher | companion
    speed_mps: float = 1.0  # preferred walking speed
    moving: float = 0.0  # current speed (m/s)
    route: list[tuple[float, float]] = field(default_factory=list)
    node: int = -1  # lane node the walker last left
    prev_node: int = -1
    wait_until: float = 0.0
    start_s: float = 0.0  # approacher: when to set off
    stay_s: float = 0.0  # approacher: how long to stay
    stay_until: float = -1.0
    phase: float = 0.0  # leg swing phase (rad)
    planned: bool = False  # approacher: route to the robot chosen
    fixed: bool = False  # scenario person with a fixed patrol (no lanes)
    patrol: list[tuple[float, float]] = field(default_factory=list)
    waited_s: float = 0.0  # walker: how long it has been held up at the robot (s)
    aside: list[tuple[float, float]] = field(default_factory=list)  # asked to make way: going there
    ignores: bool | None = None  # decided at the first "excuse me": stays put when asked
    leader: int = -1  # companion: the id of the walker it walks with
    slot: int = 0  # companion: its place in the group (sim/walking_group.py's slots)


class Lanes:
    """The walking graph: nodes (m) and edges with a lateral half-width (m)."""

    def __init__(self, nodes: list[list[float]], edges: list[list[float]]) -> None:
        self.nodes = np.asarray(nodes, dtype=np.float64).reshape(-1, 2)
        self.adj: list[list[tuple[int, float]]] = [[] for _ in range(len(self.nodes))]
        for a, b, h in edges:
            self.adj[int(a)].append((int(b), float(h)))
            self.adj[int(b)].append((int(a), float(h)))

    @classmethod
    def from_dict(cls, data: dict[str, Any] | None) -> Lanes | None:
        if not data or not data.get("nodes"):
            return None
        return cls(data["nodes"], data.get("edges", []))

    def path(self, a: int, b: int) -> list[int]:
        """Shortest node path from ``a`` to ``b`` (Dijkstra on edge lengths); [] if none."""
        dist, prev, heap = {a: 0.0}, {a: -1}, [(0.0, a)]
        while heap:
            d, u = heapq.heappop(heap)
            if u == b:
                break
            if d > dist[u]:
                continue
            for v, _ in self.adj[u]:
                nd = d + float(np.hypot(*(self.nodes[v] - self.nodes[u])))
                if nd < dist.get(v, math.inf):
                    dist[v], prev[v] = nd, u
                    heapq.heappush(heap, (nd, v))
        if b not in prev:
            return []
        out = [b]
        while prev[out[-1]] != -1:
            out.append(prev[out[-1]])
        return out[::-1]

    def nearest(self, x: float, y: float) -> int:
        return int(np.argmin(np.hypot(self.nodes[:, 0] - x, self.nodes[:, 1] - y)))

    def random_point(
        self, rng: np.random.Generator, margin_m: float, edge: bool = False
    ) -> tuple[float, float, int]:
        """A random point on a random edge, offset sideways up to its half-width - margin
        (``edge``: exactly that far, to one side: someone standing by the wall)."""
        for _ in range(EDGE_TRIES):
            a = int(rng.integers(len(self.nodes)))
            if not self.adj[a]:
                return (float(self.nodes[a, 0]), float(self.nodes[a, 1]), a)
            b, half = self.adj[a][int(rng.integers(len(self.adj[a])))]
            if not edge or half >= CORRIDOR_HALF_MIN_M:  # by a wall means a corridor's wall
                break
        f = float(rng.uniform(0.1, 0.9))
        p = self.nodes[a] + f * (self.nodes[b] - self.nodes[a])
        side = float(rng.choice([-1.0, 1.0])) if edge else float(rng.uniform(-1, 1))
        off = _lateral(self.nodes[a], self.nodes[b]) * side * max(half - margin_m, 0.0)
        return (float(p[0] + off[0]), float(p[1] + off[1]), a)


def _lateral(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    d = b - a
    n = float(np.hypot(d[0], d[1])) or 1.0
    return np.array([-d[1] / n, d[0] / n])


Clearance = Any  # callable (x, y) -> metres to the nearest wall (float)


class Crowd:
    """Every simulated person, stepped together (the ``simple`` backend of ``sim/crowd.py``)."""

    def __init__(
        self,
        people: list[PersonState],
        lanes: Lanes | None,
        clearance: Clearance,
        rng: np.random.Generator,
        line_of_sight: Any = None,
    ) -> None:
        self.people, self.lanes, self.clearance, self.rng = people, lanes, clearance, rng
        self.line_of_sight = line_of_sight  # (x0, y0, x1, y1) -> bool, for the approacher
        self.is_free: Any = None  # (x, y) -> bool: known-free floor (random targets stay on it)
        self.robot_speed = 0.0  # m/s, set by the world each step (the approacher waits for a stop)
        self._by_id = {p.id: p for p in people}
        self._companions: dict[int, list[PersonState]] = {}
        for p in people:
            if p.behaviour == "companion":
                self._companions.setdefault(p.leader, []).append(p)

    # ---------------------------------------------------------------- geometry
    def bodies(self) -> np.ndarray:
        """(n, 3): x, y, radius of every body (m)."""
        return np.array([[p.x, p.y, PERSON_RADIUS_M] for p in self.people], dtype=np.float64).reshape(-1, 3)

    def legs(self) -> np.ndarray:
        """(2n, 3): x, y, radius of every leg (m): what a lidar at knee-to-hip height sees."""
        out = np.empty((2 * len(self.people), 3))
        for i, p in enumerate(self.people):
            c, s = math.cos(p.theta), math.sin(p.theta)
            swing = STRIDE_M * math.sin(p.phase)
            for j, side in enumerate((1.0, -1.0)):
                fwd = swing * side
                out[2 * i + j] = (
                    p.x + c * fwd - s * side * LEG_HALF_SPACING_M,
                    p.y + s * fwd + c * side * LEG_HALF_SPACING_M,
                    LEG_RADIUS_M,
                )
        return out

    # ---------------------------------------------------------------- stepping
    def step(self, dt: float, t: float, robot: tuple[float, float, float], robot_radius: float) -> None:
        for p in self.people:
            goal = self._goal(p, t, robot)
            if goal is None:
                p.moving = 0.0
                if p.behaviour == "approacher" and p.stay_until > t:
                    p.theta = math.atan2(robot[1] - p.y, robot[0] - p.x)
                continue
            self._move_toward(p, goal, dt, robot, robot_radius)

    def send_aside(self, person: PersonState, path: list[tuple[float, float]]) -> None:
        """Asked to make way: walk along ``path`` (m), then carry on (standers stand there)."""
        person.aside = list(path)

    def _goal(
        self, p: PersonState, t: float, robot: tuple[float, float, float]
    ) -> tuple[float, float] | None:
        while p.aside and math.hypot(p.aside[0][0] - p.x, p.aside[0][1] - p.y) < ARRIVE_M:
            p.aside.pop(0)
        if p.aside:
            return p.aside[0]
        if p.behaviour == "companion":
            return self._companion_goal(p)
        if p.behaviour in ("stander", "group"):
            return None
        if p.wait_until > t:
            return None
        if p.behaviour == "approacher":
            return self._approach_goal(p, t, robot)
        if self._waits_for_companions(p):
            return None
        while p.route and math.hypot(p.route[0][0] - p.x, p.route[0][1] - p.y) < ARRIVE_M:
            p.route.pop(0)
            if self.rng.random() < STOP_PROBABILITY:
                p.wait_until = t + float(self.rng.uniform(*STAND_S))
                return None
        if not p.route:
            self._plan(p)
        return p.route[0] if p.route else None

    def _companion_goal(self, p: PersonState) -> tuple[float, float] | None:
        """A companion's next goal: its slot beside or behind its leader (and its speed, set
        on ``p``); None to stand with a standing leader. Without a leader it walks alone."""
        leader = self._by_id.get(p.leader)
        if leader is None or leader is p:
            p.behaviour = "walker"
            return None
        size = len(self._companions.get(p.leader, [])) + 1
        slot = walking_group.slots(size)[min(p.slot, size - 2)]
        found = walking_group.companion_goal(
            (p.x, p.y), (leader.x, leader.y, leader.theta), leader.moving, slot, self._free)
        if found is None:
            return None
        goal, p.speed_mps = found
        return goal

    def _waits_for_companions(self, p: PersonState) -> bool:
        """A group's leader waits while a companion on its way is far behind its slot."""
        group = self._companions.get(p.id)
        if not group:
            return False
        slots = walking_group.slots(len(group) + 1)
        here = (p.x, p.y, p.theta)
        return any(c.moving > WAITING_MPS and not c.aside
                   and walking_group.lagging((c.x, c.y), here, slots[min(c.slot, len(slots) - 1)])
                   for c in group)

    def _approach_goal(
        self, p: PersonState, t: float, robot: tuple[float, float, float]
    ) -> tuple[float, float] | None:
        if t < p.start_s:
            return None
        if p.stay_until < 0.0 and self.robot_speed > APPROACH_MAX_ROBOT_MPS:
            if p.planned:  # the robot drove off while they came: they walk on
                p.behaviour = "walker"
                p.route.clear()
            return None  # else wait until it stands still
        if p.stay_until >= 0.0:
            if t < p.stay_until:
                return None
            p.behaviour = "walker"  # said what they wanted: walk on
            p.route.clear()
            return None
        gx = robot[0] + APPROACH_STOP_M * math.cos(robot[2])
        gy = robot[1] + APPROACH_STOP_M * math.sin(robot[2])
        if math.hypot(gx - p.x, gy - p.y) < ARRIVE_M or math.hypot(robot[0] - p.x, robot[1] - p.y) <= (
            APPROACH_STOP_M + ARRIVE_M
        ):
            p.stay_until = t + p.stay_s
            return None
        p.speed_mps = APPROACH_SPEED_MPS
        if not p.planned:
            p.planned = True
            if (
                self.lanes is not None
                and self.line_of_sight is not None
                and not self.line_of_sight(p.x, p.y, gx, gy)
            ):
                nodes = self.lanes.path(self.lanes.nearest(p.x, p.y), self.lanes.nearest(gx, gy))
                p.route = [(float(self.lanes.nodes[n, 0]), float(self.lanes.nodes[n, 1])) for n in nodes]
        while p.route and math.hypot(p.route[0][0] - p.x, p.route[0][1] - p.y) < ARRIVE_M:
            p.route.pop(0)
        return p.route[0] if p.route else (gx, gy)

    def _plan(self, p: PersonState) -> None:
        """Next waypoint: along the lanes (random walk, no immediate U-turn), the patrol, or
        a random spot with clearance when the map has no lanes."""
        if p.patrol:
            p.route.append(p.patrol[0])
            p.patrol.append(p.patrol.pop(0))
            return
        if self.lanes is None:
            p.route.append(self._random_free(p))
            return
        lanes = self.lanes
        if p.node < 0:
            p.node = lanes.nearest(p.x, p.y)
            p.route.append((float(lanes.nodes[p.node, 0]), float(lanes.nodes[p.node, 1])))
            return
        options = [(b, h) for b, h in lanes.adj[p.node] if b != p.prev_node] or lanes.adj[p.node]
        if not options:
            return
        b, half = options[int(self.rng.integers(len(options)))]
        off = (
            _lateral(lanes.nodes[p.node], lanes.nodes[b])
            * self.rng.uniform(-1, 1)
            * max(half - PERSON_RADIUS_M - 0.1, 0.0)
        )
        target = lanes.nodes[b] + off
        p.route.append((float(target[0]), float(target[1])))
        p.prev_node, p.node = p.node, b

    def _turn_back(self, p: PersonState, robot: tuple[float, float, float] | None = None) -> None:
        """Give up waiting for the robot: back along the lane it came by (walkers on lanes), or,
        on a map without lanes, off to another spot on its own side of the robot (it used to
        keep waiting there, in the robot's way, while the robot waited for it; JuPedSim's
        guard stops people short of the robot, so they never got round it). A way aside that
        leads past the robot is given up too: it came before the new route, and a person asked
        aside stood for good at the goal the robot waited to reach (measured on the sandbox)."""
        p.waited_s = 0.0
        p.aside.clear()
        if p.behaviour != "walker" or p.patrol:
            return
        if self.lanes is None:
            p.route = [self._random_free(p, away_from=robot)]
            return
        if p.prev_node < 0:
            return
        back = self.lanes.nodes[p.prev_node]
        p.route = [(float(back[0]), float(back[1]))]
        p.prev_node, p.node = p.node, p.prev_node

    def _random_free(self, p: PersonState, away_from: tuple[float, float, float] | None = None
                     ) -> tuple[float, float]:
        """A random spot with room (ROOMY_M from walls), within 8 m. With ``away_from`` (the
        robot's pose): one on the far side of the person from it, with room for a body where
        no roomy one is drawn (a narrow corridor); where the person stands when none is."""
        relaxed = None
        for _ in range(50):
            x = p.x + float(self.rng.uniform(-RANDOM_SPOT_M, RANDOM_SPOT_M))
            y = p.y + float(self.rng.uniform(-RANDOM_SPOT_M, RANDOM_SPOT_M))
            away = away_from is None or (
                (x - p.x) * (away_from[0] - p.x) + (y - p.y) * (away_from[1] - p.y) < 0.0)
            if not away or not self._free(x, y):
                continue
            if self.clearance(x, y) > PERSON_RADIUS_M + ROOMY_M:
                return (x, y)
            relaxed = relaxed or ((x, y) if away_from is not None else None)
        return relaxed or (p.x, p.y)

    def _free(self, x: float, y: float) -> bool:
        return self.clearance(x, y) >= PERSON_RADIUS_M + WALL_MARGIN_M and (
            self.is_free is None or self.is_free(x, y)
        )

    def _around_robot_step(self, p: PersonState, ux: float, uy: float, step: float,
                           robot: tuple[float, float, float], keep: float) -> tuple[float, float] | None:
        """A step of ``step`` m around the robot, ``keep`` m from its centre, toward whichever
        side of it (across the walker's heading ``ux``, ``uy``) has room to pass, the nearer
        first; None when neither has (the robot fills the corridor)."""
        r = math.hypot(p.x - robot[0], p.y - robot[1])
        sides = [(robot[0] - s * uy * keep, robot[1] + s * ux * keep) for s in (1.0, -1.0)]
        sides.sort(key=lambda q: math.hypot(q[0] - p.x, q[1] - p.y))
        passing = next((q for q in sides if self._free(*q)), None)
        if passing is None or r < 1e-6:
            return None
        tx, ty = -(p.y - robot[1]) / r, (p.x - robot[0]) / r  # tangent of the circle
        if tx * (passing[0] - p.x) + ty * (passing[1] - p.y) < 0.0:
            tx, ty = -tx, -ty
        cx, cy = p.x + tx * step - robot[0], p.y + ty * step - robot[1]
        scale = max(keep, r) / max(math.hypot(cx, cy), 1e-6)
        x, y = robot[0] + cx * scale, robot[1] + cy * scale
        return (x, y) if self._free(x, y) else None

    def _around_halted_robot(self, p: PersonState, ux: float, uy: float, step: float,
                             robot: tuple[float, float, float], keep: float) -> tuple[float, float] | None:
        """People in a corridor walk around a robot that stands still (it waits for them);
        a moving robot, or one that leaves no room, is waited for."""
        if p.behaviour not in WALKING or self.robot_speed > ROBOT_HALTED_MPS:
            return None
        return self._around_robot_step(p, ux, uy, step, robot, keep)

    def _move_toward(
        self,
        p: PersonState,
        goal: tuple[float, float],
        dt: float,
        robot: tuple[float, float, float],
        rr: float,
    ) -> None:
        dx, dy = goal[0] - p.x, goal[1] - p.y
        dist = math.hypot(dx, dy)
        if dist < 1e-6:
            return
        ux, uy = dx / dist, dy / dist
        if p.behaviour == "walker" and math.hypot(robot[0] - p.x, robot[1] - p.y) < (
            PERSON_RADIUS_M + rr + ROBOT_GAP_M + HELD_UP_M
        ):
            p.waited_s += dt  # held up at the robot: waiting, or circling it without getting by
            if p.waited_s >= TURN_BACK_S:
                self._turn_back(p, robot)
                return
        else:
            p.waited_s = 0.0
        step = min(p.speed_mps * dt, dist)
        vx, vy = ux * step, uy * step
        rx, ry = robot[0] - p.x, robot[1] - p.y
        ahead = rx * ux + ry * uy
        if p.behaviour in WALKING and 0.0 < ahead < AVOID_LOOKAHEAD_M + rr:
            side = -1.0 if (ux * ry - uy * rx) > 0 else 1.0  # away from the robot
            vx += -uy * side * SIDESTEP_MPS * dt
            vy += ux * side * SIDESTEP_MPS * dt
        nx, ny = p.x + vx, p.y + vy
        keep = PERSON_RADIUS_M + rr + ROBOT_GAP_M
        if math.hypot(robot[0] - nx, robot[1] - ny) < keep and math.hypot(rx, ry) >= math.hypot(
            robot[0] - nx, robot[1] - ny
        ):
            around = self._around_halted_robot(p, ux, uy, step, robot, keep)
            if around is None:
                p.moving = 0.0  # would walk into the robot: wait
                return
            nx, ny = around
        if not self._free(nx, ny):
            # Blocked by a wall: slide along it (the larger axis of the move first); if that
            # fails too, give up this waypoint.
            slides = [(p.x + vx, p.y), (p.x, p.y + vy)]
            if abs(vy) > abs(vx):
                slides.reverse()
            free = [s for s in slides if self._free(*s)]
            if not free:
                p.moving = 0.0
                if p.route:
                    p.route.pop(0)
                return
            nx, ny = free[0]
        moved = math.hypot(nx - p.x, ny - p.y)
        p.x, p.y, p.theta = nx, ny, math.atan2(uy, ux)
        p.moving = moved / dt if dt > 0 else 0.0
        p.phase = (p.phase + STRIDE_RATE * moved) % (2 * math.pi)
