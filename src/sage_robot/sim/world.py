"""The simulated world: the building's map, the robot's body, low obstacles and people.

The firmware model (``sim/firmware``) moves the body through :meth:`World.drive` at every
100 Hz physics step; the world node steps the people with :meth:`World.step` and asks for
scans, camera frames and the speaker's bearing. Nothing here touches the bus or the
clock: time comes in as ``dt`` and ``World.t``.

Map frame, metres, radians (x east, y north, theta counter-clockwise). The body is a
circle of ``robot_radius`` m. A move that would overlap a wall, a low obstacle or a
person does not happen (the body stops, turning in place still works); each new contact
counts as one collision and is reported to the ``on_collision`` callbacks.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from sage_robot.core.msgs import CompressedImage, LaserScan, OccupancyGrid
from sage_robot.core.msgs.sim import LowObstacle, People, Person, SpeakerBearing, bearing_to_doa_deg
from sage_robot.sim.camera import Camera, Scene, encode_jpeg
from sage_robot.sim.crowd import aside_path, asked_people, make_crowd, person_fits
from sage_robot.sim.lidar import Lidar, LidarSpec
from sage_robot.sim.people import PERSON_RADIUS_M, Lanes, PersonState
from sage_robot.sim.raycast import GridRaycaster

SPEAKER_RANGE_M = 3.0  # the nearest person within this distance is "the speaker"
TURN_EPS_RADPS = 1e-9
IGNORE_STREAM = 3  # SeedSequence child for who ignores "excuse me" (0, 1: world; 2: spawning)


@dataclass(frozen=True)
class Collision:
    """One new contact: what was hit (``kind`` wall | low_obstacle | person, ``name``), where
    the body stood (m) and how fast it was going (m/s)."""

    t: float
    kind: str
    name: str
    x: float
    y: float
    speed_mps: float


class World:
    def __init__(
        self,
        grid: OccupancyGrid,
        start: tuple[float, float, float],
        *,
        robot_radius: float = 0.25,
        lidar: LidarSpec | None = None,
        low_obstacles: tuple[LowObstacle, ...] = (),
        people: list[PersonState] | None = None,
        lanes: Lanes | None = None,
        seed: int = 7,
        raycaster: GridRaycaster | None = None,
        track_width_m: float = 0.381,
        people_model: str = "simple",
        ignore_share: float = 0.0,
    ) -> None:
        self.grid = grid
        self.raycaster = raycaster or GridRaycaster(grid)
        self.robot_radius = robot_radius
        self.track_width_m = track_width_m
        self.body = WorldBody(self)
        seeds = np.random.SeedSequence(seed).spawn(2)
        self.rng_people, self.rng_lidar = (np.random.default_rng(s) for s in seeds)
        self.lidar = Lidar(lidar or LidarSpec(), self.raycaster, self.rng_lidar)
        self.low_obstacles = tuple(low_obstacles)
        self._boxes = np.array(
            [[o.x, o.y, o.length_m, o.depth_m, o.yaw, o.height_m] for o in self.low_obstacles],
            dtype=np.float64,
        ).reshape(-1, 6)
        # Centre and half-diagonal + body radius of each box: farther away, no contact possible.
        self._box_reach = [
            (float(b[0]), float(b[1]), 0.5 * math.hypot(b[2], b[3]) + robot_radius) for b in self._boxes
        ]
        if not 0.0 <= ignore_share <= 1.0:
            raise ValueError(f"the share of people who ignore the robot must be 0..1, got {ignore_share}")
        self.ignore_share = ignore_share
        self.rng_ignore = np.random.default_rng(np.random.SeedSequence(seed).spawn(IGNORE_STREAM + 1)[-1])
        self.crowd = make_crowd(
            people_model, list(people or []), lanes, self.raycaster.clearance_at, self.rng_people,
            self.line_of_sight, grid=grid, start=start, robot_radius=robot_radius,
        )
        self.crowd.is_free = self.raycaster.is_free
        self._camera: Camera | None = None
        self.x, self.y, self.theta = start
        self.v = self.w = 0.0
        self.t = 0.0
        self.distance_m = 0.0
        self.collisions = 0
        self.collisions_by_kind: Counter[str] = Counter()
        self.on_collision: list[Callable[[Collision], None]] = []
        self._contacts: set[str] = set()
        self.drive_calls = 0
        blocked = self._blockers(self.x, self.y)
        if blocked:
            raise ValueError(
                f"the robot's start ({self.x:.2f}, {self.y:.2f}) overlaps {', '.join(sorted(blocked))}"
            )

    # ---------------------------------------------------------------- body
    @property
    def pose(self) -> tuple[float, float, float]:
        return (self.x, self.y, self.theta)

    def drive(
        self, dt: float, left_mps: float, right_mps: float, track_width_m: float
    ) -> tuple[float, float]:
        """Move the body for ``dt`` s by differential-drive wheel speeds (m/s).

        Returns the true body twist (v m/s, w rad/s): v is 0 when the move was blocked."""
        self.drive_calls += 1
        v = (left_mps + right_mps) / 2.0
        w = (right_mps - left_mps) / track_width_m
        return self.move(dt, v, w)

    def move(self, dt: float, v: float, w: float) -> tuple[float, float]:
        """Move the body for ``dt`` s at body twist (v m/s, w rad/s); the true twist comes back."""
        mid = self.theta + 0.5 * w * dt
        nx, ny = self.x + v * dt * math.cos(mid), self.y + v * dt * math.sin(mid)
        blocked = self._blockers(nx, ny) if v != 0.0 else set()
        for name in sorted(blocked - self._contacts):
            kind = name.split(":", 1)[0]
            self.collisions += 1
            self.collisions_by_kind[kind] += 1
            event = Collision(self.t, kind, name, self.x, self.y, abs(v))
            for cb in self.on_collision:
                cb(event)
        self._contacts = blocked
        if blocked:
            v = 0.0
        else:
            self.distance_m += math.hypot(nx - self.x, ny - self.y)
            self.x, self.y = nx, ny
        self.theta = math.atan2(math.sin(self.theta + w * dt), math.cos(self.theta + w * dt))
        self.v, self.w = v, w
        return (v, w)

    def _blockers(self, x: float, y: float) -> set[str]:
        """Everything a body at (x, y) would overlap, as 'kind:name' strings."""
        r = self.robot_radius
        out = set()
        if self.raycaster.clearance_at(x, y) < r:
            out.add("wall:map")
        for i, (bx, by, reach) in enumerate(self._box_reach):
            near = abs(x - bx) < reach and abs(y - by) < reach  # cheap test first
            if near and float(_box_distance(x, y, self._boxes[i : i + 1])[0]) < r:
                out.add(f"low_obstacle:{self.low_obstacles[i].name}")
        for p in self.crowd.people:
            if math.hypot(p.x - x, p.y - y) < r + PERSON_RADIUS_M:
                out.add(f"person:{p.id}")
        return out

    def line_of_sight(self, x0: float, y0: float, x1: float, y1: float) -> bool:
        """True when no wall lies between the two points (m)."""
        d = math.hypot(x1 - x0, y1 - y0)
        if d < 1e-9:
            return True
        hit = self.raycaster.cast(x0, y0, np.array([math.atan2(y1 - y0, x1 - x0)]), d + 0.1)[0]
        return bool(hit >= d)

    # ---------------------------------------------------------------- people
    def step(self, dt: float) -> None:
        """Advance the world's own time and its people by ``dt`` s."""
        self.crowd.robot_speed = abs(self.v)
        self.crowd.step(dt, self.t, self.pose, self.robot_radius)
        self.t += dt

    def ask_aside(self) -> list[int]:
        """The robot said "excuse me": people in front of it step out of its way (a seeded
        ``ignore_share`` of them, decided once per person, stay put; so does someone with
        nowhere to go). Returns the ids of those who move."""
        fits = person_fits(self.raycaster.clearance_at, self.raycaster.is_free)
        moving = []
        for p in asked_people(self.crowd.people, self.pose):
            if p.ignores is None:
                p.ignores = bool(self.rng_ignore.random() < self.ignore_share)
            path = [] if p.ignores else aside_path(p, self.pose, self.robot_radius, fits)
            if path:
                self.crowd.send_aside(p, path)
                moving.append(p.id)
        return moving

    def people_msg(self, stamp: float) -> People:
        return People(
            stamp,
            tuple(
                Person(p.id, p.x, p.y, p.theta, p.moving, p.behaviour, PERSON_RADIUS_M)
                for p in self.crowd.people
            ),
        )

    def speaker(self, stamp: float) -> SpeakerBearing:
        """The nearest person within SPEAKER_RANGE_M, as a DOA angle (seed convention)."""
        best, best_d = None, SPEAKER_RANGE_M
        for p in self.crowd.people:
            d = math.hypot(p.x - self.x, p.y - self.y)
            if d <= best_d:
                best, best_d = p, d
        if best is None:
            return SpeakerBearing(stamp, False)
        bearing = math.atan2(best.y - self.y, best.x - self.x) - self.theta
        return SpeakerBearing(stamp, True, bearing_to_doa_deg(bearing), best_d, best.id)

    # ---------------------------------------------------------------- sensors
    def tall_boxes(self) -> np.ndarray:
        """Boxes that reach the scan plane (the lidar sees them); (k, 5)."""
        tall = self._boxes[:, 5] >= self.lidar.spec.mount_z_m
        return self._boxes[tall, :5]

    def scan(self, stamp: float) -> LaserScan:
        return self.lidar.scan(stamp, self.pose, self.crowd.legs(), self.tall_boxes())

    def scene(self) -> Scene:
        people = np.array([[p.x, p.y, PERSON_RADIUS_M, p.id] for p in self.crowd.people]).reshape(-1, 4)
        return Scene(people, self._boxes, tuple(o.kind for o in self.low_obstacles))

    @property
    def camera(self) -> Camera:
        if self._camera is None:
            self._camera = Camera(self.raycaster)
        return self._camera

    def camera_image(self) -> np.ndarray:
        return self.camera.render(self.pose, self.scene())

    def camera_msg(self, stamp: float) -> CompressedImage:
        return CompressedImage(stamp, "camera", "jpeg", encode_jpeg(self.camera_image()))

    def summary(self) -> dict[str, object]:
        return {
            "sim_time_s": round(self.t, 3),
            "distance_m": round(self.distance_m, 3),
            "collisions": self.collisions,
            "collisions_by_kind": dict(sorted(self.collisions_by_kind.items())),
            "pose": [round(self.x, 3), round(self.y, 3), round(self.theta, 4)],
        }


class WorldBody:
    """The world's robot body as the firmware model's ``SimBody`` (``sim/flat_floor.py``):
    ``step(dt, (left, right))`` with wheel ground speeds in m/s → true (v, w)."""

    def __init__(self, world: World) -> None:
        self.world = world

    def step(self, dt: float, wheel_speeds: tuple[float, float]) -> tuple[float, float]:
        left, right = wheel_speeds
        return self.world.drive(dt, left, right, self.world.track_width_m)

    @property
    def pose(self) -> tuple[float, float, float]:
        return self.world.pose


def _box_distance(x: float, y: float, boxes: np.ndarray) -> np.ndarray:
    """Distance (m) from a point to each oriented box (k, >=5: x, y, length, depth, yaw); 0 inside."""
    c, s = np.cos(boxes[:, 4]), np.sin(boxes[:, 4])
    dx, dy = x - boxes[:, 0], y - boxes[:, 1]
    lx, ly = np.abs(c * dx + s * dy), np.abs(-s * dx + c * dy)
    ex, ey = np.maximum(lx - boxes[:, 2] / 2, 0.0), np.maximum(ly - boxes[:, 3] / 2, 0.0)
    dist: np.ndarray = np.hypot(ex, ey)
    return dist
