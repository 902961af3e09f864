"""A minimal simulator for navigation tests, driving the real nodes through the real bus.

A kinematic differential-drive body on a grid (a move that would overlap a wall or a
person does not happen and counts as a collision), wheel odometry with a scale error,
a 360-beam raycast lidar at 10 Hz and people as circles the test moves. Every
``/cmd_vel`` is recorded so tests can check that reverse is never commanded.
Map frame, metres, radians. Time only from the SimClock.
"""

from __future__ import annotations

import asyncio
import math
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from scipy import ndimage

from sage_robot.core import topics
from sage_robot.core.bus import Bus
from sage_robot.core.clock import SimClock
from sage_robot.core.config import Settings
from sage_robot.core.geometry import compose, wrap_angle
from sage_robot.core.mapio import write_map
from sage_robot.core.msgs import Imu, LaserScan, OccupancyGrid, Odometry, Pose2D, Twist
from sage_robot.core.node import NodeContext

from .nav_raycast import RANGE_MAX_M, RANGE_MIN_M, beam_angles, cast

STEP_S = 0.05  # physics step (s)
SCAN_EVERY = 2  # steps per scan: 10 Hz
WATCHDOG_S = 0.55  # the MCU stops a command older than this (s)
RANGE_NOISE_M = 0.01
PERSON_RADIUS_M = 0.25


class KinematicSim:
    def __init__(self, bus: Bus, grid: OccupancyGrid, start: tuple[float, float, float], settings: Settings,
                 odom_scale: float = 1.0, seed: int = 0, odom_w_scale: float = 1.0,
                 imu: bool = False) -> None:
        self.bus, self.grid, self.settings = bus, grid, settings
        self.pose = start
        self.odom = (0.0, 0.0, 0.0)  # odometry starts at zero, as the MCU's does
        self.odom_scale = odom_scale
        self.odom_w_scale = odom_w_scale  # wheel yaw rate error (slip, tilted dead wheels)
        self.imu = imu
        self.rng = np.random.default_rng(seed)
        self.clearance = ndimage.distance_transform_edt(grid.data < 50) * grid.resolution
        self.people: list[list[float]] = []  # [x, y] each, radius PERSON_RADIUS_M
        self.cmd = Twist()
        self.cmd_t = -math.inf
        self.cmds: list[tuple[float, Twist, tuple[float, float, float]]] = []
        self.collisions = 0
        self.truth: list[tuple[float, float, float, float]] = []  # t, x, y, theta
        self._contact = False
        self.t = 0.0
        self.k = 0
        self.nodes: list[Any] = []
        self.angles = beam_angles()
        bus.subscribe(topics.CMD_VEL, Twist, self._on_cmd, maxsize=1000)

    def _on_cmd(self, msg: Twist) -> None:
        self.cmd, self.cmd_t = msg, self.t
        self.cmds.append((self.t, msg, self.pose))

    def _free(self, x: float, y: float) -> bool:
        g = self.grid
        r = int((y - g.origin.y) / g.resolution)
        c = int((x - g.origin.x) / g.resolution)
        if not (0 <= r < g.height and 0 <= c < g.width):
            return False
        if self.clearance[r, c] < self.settings.robot.radius_m:
            return False
        return all(math.hypot(px - x, py - y) >= self.settings.robot.radius_m + PERSON_RADIUS_M
                   for px, py in self.people)

    def teleport(self, x: float, y: float, theta: float) -> None:
        self.pose = (x, y, theta)

    def step(self, dt: float) -> None:
        self.t += dt
        self.k += 1
        v, w = (self.cmd.linear_x, self.cmd.angular_z) if self.t - self.cmd_t < WATCHDOG_S else (0.0, 0.0)
        x, y, th = self.pose
        nx, ny = x + v * dt * math.cos(th + 0.5 * w * dt), y + v * dt * math.sin(th + 0.5 * w * dt)
        if v != 0.0 and not self._free(nx, ny):
            if not self._contact:
                self.collisions += 1
            self._contact = True
            nx, ny, v = x, y, 0.0
        else:
            self._contact = False
        self.pose = (nx, ny, wrap_angle(th + w * dt))
        ox, oy, oth = self.odom
        d, wo = v * dt * self.odom_scale, w * self.odom_w_scale
        self.odom = (ox + d * math.cos(oth + 0.5 * wo * dt), oy + d * math.sin(oth + 0.5 * wo * dt),
                     wrap_angle(oth + wo * dt))
        self.bus.publish(topics.ODOM, Odometry(self.t, Pose2D(*self.odom), Twist(v * self.odom_scale, wo)))
        if self.imu:
            self.bus.publish(topics.IMU, Imu(self.t, (0.0, 0.0, w), (0.0, 0.0, 9.81)))
        if self.k % SCAN_EVERY == 0:
            self.truth.append((self.t, *self.pose))
            self.bus.publish(topics.SCAN, self.scan())

    def scan(self) -> LaserScan:
        lm = self.settings.robot.lidar
        origin = compose(self.pose, (lm.x_m, lm.y_m, lm.yaw_rad))
        people = [(px, py, PERSON_RADIUS_M) for px, py in self.people]
        r = cast(self.grid, origin, self.angles, people)
        r = r + self.rng.normal(0.0, RANGE_NOISE_M, len(r)).astype(np.float32)
        return LaserScan(self.t, "laser", -math.pi, 2 * math.pi / len(self.angles), RANGE_MIN_M, RANGE_MAX_M,
                         r.astype(np.float32))

    def reversed_commands(self) -> list[Twist]:
        return [c for _, c, _ in self.cmds if c.linear_x < 0.0]


def write_building(tmp: Path, grid: OccupancyGrid, places: dict[str, tuple[float, float, float]],
                   keepout: OccupancyGrid | None = None, speed: OccupancyGrid | None = None) -> Path:
    """A map folder as the robot has it: map.yaml/pgm, waypoints.yaml and optional masks."""
    path = write_map(grid, tmp / "map.yaml")
    if keepout is not None:
        write_map(keepout, tmp / "map_keepout.yaml")
    if speed is not None:
        write_map(speed, tmp / "map_speed.yaml", mode="raw")
    wp = {"places": [{"name": n, "pose": list(p), "aliases": [n.lower().replace("_", " ")]}
                     for n, p in places.items()]}
    (tmp / "waypoints.yaml").write_text(yaml.safe_dump(wp), encoding="utf-8")
    return path


def settings_for(map_path: Path, start_place: str, **nav: Any) -> Settings:
    return Settings.model_validate({"nav": {"map": str(map_path), "initial_place": start_place, **nav}})


@asynccontextmanager
async def running(settings: Settings, grid: OccupancyGrid, start: tuple[float, float, float],
                  speed: float | None = None, **sim_kw: Any):
    """Start map_server, localization and navigator on a SimClock with the simulator stepping.

    By default the clock runs as fast as the machine computes (``speed`` None): planning and
    localization are offloaded in lockstep with it, so no result depends on wall time or load.
    A paced run (``speed`` > 0) would let the test's own steps land between simulator steps
    differently on a quiet and on a busy machine."""
    from sage_robot.nav.localization import LocalizationNode
    from sage_robot.nav.map_server import MapServerNode
    from sage_robot.nav.navigator import NavigatorNode

    clock = SimClock()
    bus = Bus(clock)
    ctx = NodeContext(bus, clock, settings)
    sim = KinematicSim(bus, grid, start, settings, **sim_kw)
    nodes = [MapServerNode(ctx), LocalizationNode(ctx), NavigatorNode(ctx)]
    sim.nodes = nodes  # for tests that restart one
    for n in nodes:
        await n.setup()
    stop = asyncio.Event()
    stepper = asyncio.get_running_loop().create_task(clock.run(STEP_S, speed, None, stop, sim.step))
    try:
        await asyncio.sleep(0)
        yield bus, clock, sim
    finally:
        stop.set()
        await asyncio.wait_for(stepper, 10)
        for n in nodes:
            await n.teardown()
            await n._close()
