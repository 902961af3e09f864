"""The simulated world of the SLAM bench: a map with clutter, walking people, the robot's lidar
and drifting wheel odometry, stepped scan by scan along a list of true poses.

- *Clutter*: boxes (``CLUTTER_SIDE_M``, one per ``CLUTTER_AREA_M2`` of free floor, at most
  ``MAX_CLUTTER``) drawn into a copy of the map, at least ``CLUTTER_ROUTE_GAP_M`` from the
  drive. They are part of the world: the scans see them and the map is scored against them.
- *People*: walkers of :mod:`sage_robot.sim.people` (one per ``PEOPLE_AREA_M2`` of free floor,
  at most ``MAX_PEOPLE``) wandering to random free spots; the lidar sees their legs.
- *Lidar*: :class:`sage_robot.sim.lidar.Lidar` with the robot's spec (RPLIDAR A1M8: 360 beams,
  12 m, 1 % range noise, dropouts, mounted 0.15 m ahead of the base).
- *Odometry*: wheel odometry with a systematic scale error (``ODOM_SCALE_ERROR``), a turn
  scale error (``TURN_SCALE_ERROR``), a heading drift per metre (``YAW_DRIFT_RAD_PER_M``) and
  random noise growing with the square root of the distance.
- *Gyro* (``gyro=True``, the robot's BNO08x after the serial bridge's start-up calibration):
  the turn with a scale error (``GYRO_SCALE_ERROR``), a residual bias drawn once
  (``GYRO_BIAS_RADPS``) and an angle random walk (``GYRO_NOISE_RAD_PER_SQRT_S``), integrated
  scan by scan (:attr:`SimDrive.gyro_yaw`).

The map's unknown cells are solid in this world (some source maps draw most walls as the
edge of the known floor). ``seen`` counts, per cell of the true grid, the lidar returns that
ended in it (from the true ranges): the walls the robot could have mapped.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from sage_robot.core.geometry import compose, relative

Pose = tuple[float, float, float]

SCAN_PERIOD_S = 0.2  # SLAM takes a scan every 0.2 s (the lidar runs at 10 Hz)
CLUTTER_SIDE_M = (0.3, 0.8)
CLUTTER_AREA_M2 = 40.0
MAX_CLUTTER = 60
CLUTTER_ROUTE_GAP_M = 0.8  # clutter keeps this far from every pose of the drive
PEOPLE_AREA_M2 = 150.0
MAX_PEOPLE = 8
PEOPLE_START_GAP_M = 3.0  # people start at least this far from the robot
PERSON_CLEARANCE_M = 0.6  # people start this far from walls
ROBOT_RADIUS_M = 0.25
ODOM_SCALE_ERROR = 0.02  # wheel odometry reads 2 % long (a worn tyre)
TURN_SCALE_ERROR = 0.02  # ...and turns 2 % too much (track width)
YAW_DRIFT_RAD_PER_M = 0.01  # heading creeps this much per metre driven
ODOM_NOISE_M_PER_SQRT_M = 0.01  # random translation noise (1 sigma) after 1 m
YAW_NOISE_RAD_PER_SQRT_M = 0.003  # random heading noise (1 sigma) after 1 m (or 1 rad turned)
# The robot's gyro (BNO08x, 100 Hz) after the bridge's start-up bias calibration:
GYRO_BIAS_RADPS = 0.0005  # residual bias (1 sigma, drawn once): 1.7 deg a minute
GYRO_SCALE_ERROR = 0.01  # turns read 1 % long
GYRO_NOISE_RAD_PER_SQRT_S = 0.0002  # angle random walk (0.002 rad/s white noise at 100 Hz)
SEEN_HIT_OFFSET_M = 0.01  # a true return is counted in the cell just behind its end point
PLACE_TRIES = 400


def _free_cells(grid: Any, clearance_m: float) -> np.ndarray:
    """(N, 2) centres (m) of free cells at least ``clearance_m`` from walls and unknown space."""
    from scipy.ndimage import distance_transform_edt

    dist = distance_transform_edt(grid.data == 0) * grid.resolution
    rows, cols = np.nonzero(dist >= max(clearance_m, grid.resolution))
    return np.column_stack(
        (grid.origin.x + (cols + 0.5) * grid.resolution, grid.origin.y + (rows + 0.5) * grid.resolution)
    )


def add_clutter(grid: Any, route: np.ndarray, rng: np.random.Generator) -> tuple[Any, int]:
    """A copy of ``grid`` with boxes drawn in, away from the route (x, y rows); and their count."""
    from scipy.spatial import cKDTree

    free = _free_cells(grid, 0.0)
    area = len(free) * grid.resolution**2
    want = min(MAX_CLUTTER, int(area / CLUTTER_AREA_M2))
    tree = cKDTree(route[:, :2])
    data = grid.data.copy()
    placed = 0
    for _ in range(PLACE_TRIES):
        if placed >= want or len(free) == 0:
            break
        x, y = free[int(rng.integers(len(free)))]
        side = float(rng.uniform(*CLUTTER_SIDE_M))
        if tree.query((x, y))[0] < CLUTTER_ROUTE_GAP_M + side * math.sqrt(0.5):
            continue
        half = 0.5 * side / grid.resolution
        c0, r0 = (x - grid.origin.x) / grid.resolution, (y - grid.origin.y) / grid.resolution
        rows = slice(max(0, round(r0 - half)), round(r0 + half))
        cols = slice(max(0, round(c0 - half)), round(c0 + half))
        data[rows, cols] = 100
        placed += 1
    return dataclasses.replace(grid, data=data), placed


def _spawn_people(grid: Any, start: Pose, rng: np.random.Generator) -> list[Any]:
    from sage_robot.sim.people import WALK_SPEED_MPS, PersonState

    spots = _free_cells(grid, PERSON_CLEARANCE_M)
    spots = spots[np.hypot(spots[:, 0] - start[0], spots[:, 1] - start[1]) >= PEOPLE_START_GAP_M]
    area = len(_free_cells(grid, 0.0)) * grid.resolution**2
    n = min(MAX_PEOPLE, max(1, int(area / PEOPLE_AREA_M2)), len(spots))
    people = []
    for pid in range(n):
        x, y = spots[int(rng.integers(len(spots)))]
        speed = float(rng.uniform(*WALK_SPEED_MPS))
        heading = float(rng.uniform(-math.pi, math.pi))
        people.append(PersonState(pid, float(x), float(y), heading, speed_mps=speed))
    return people


class SimDrive:
    """Steps the world along true robot poses: scans, odometry and what the lidar saw."""

    def __init__(
        self,
        grid: Any,
        truth: list[Pose],
        seed: int,
        people: bool = True,
        clutter: bool = True,
        gyro: bool = False,
    ) -> None:
        from sage_robot.sim.lidar import Lidar, LidarSpec
        from sage_robot.sim.people import Crowd
        from sage_robot.sim.raycast import GridRaycaster

        rngs = [np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(5)]
        self.rng_odom = rngs[0]
        self.rng_gyro = rngs[4] if gyro else None
        self.gyro_bias = float(rngs[4].normal(0.0, GYRO_BIAS_RADPS)) if gyro else 0.0
        self.truth = truth
        self.clutter = 0
        # Unknown space is solid: a SLAM-made source map (Willow Garage) marks most of its walls
        # as the edge of the known floor rather than as occupied cells.
        solid = np.where(grid.data < 0, np.int8(100), grid.data).astype(np.int8)
        grid = dataclasses.replace(grid, data=solid)
        if clutter:
            grid, self.clutter = add_clutter(grid, np.asarray(truth), rngs[1])
        self.grid = grid
        self.caster = GridRaycaster(grid)
        self.spec = LidarSpec()
        self.lidar = Lidar(self.spec, self.caster, rngs[2])
        crowd_people = _spawn_people(grid, truth[0], rngs[3]) if people else []
        self.crowd = Crowd(crowd_people, None, self.caster.clearance_at, rngs[3])
        self.crowd.is_free = self.caster.is_free
        self.seen = np.zeros(grid.data.shape, dtype=np.int32)
        self.odom: Pose = truth[0]
        self.gyro_yaw = 0.0  # the gyro's integrated heading (rad, from the first scan)
        self._no_boxes = np.zeros((0, 6))

    @property
    def laser(self) -> Pose:
        return (self.spec.mount_x_m, self.spec.mount_y_m, self.spec.mount_yaw_rad)

    def odometry(self, k: int) -> Pose:
        """The wheel odometry pose at scan ``k`` (call in order); with ``gyro`` it also
        advances :attr:`gyro_yaw`."""
        if k:
            dx, dy, dth = relative(self.truth[k - 1], self.truth[k])
            dist = math.hypot(dx, dy)
            rng = self.rng_odom
            sd = ODOM_NOISE_M_PER_SQRT_M * math.sqrt(dist)
            sth = YAW_NOISE_RAD_PER_SQRT_M * math.sqrt(dist + abs(dth))
            step = (
                dx * (1 + ODOM_SCALE_ERROR) + rng.normal(0, sd),
                dy + rng.normal(0, sd),
                dth * (1 + TURN_SCALE_ERROR) + YAW_DRIFT_RAD_PER_M * dist + rng.normal(0, sth),
            )
            self.odom = compose(self.odom, step)
            if self.rng_gyro is not None:
                noise = self.rng_gyro.normal(0, GYRO_NOISE_RAD_PER_SQRT_S * math.sqrt(SCAN_PERIOD_S))
                self.gyro_yaw += dth * (1 + GYRO_SCALE_ERROR) + self.gyro_bias * SCAN_PERIOD_S + noise
        return self.odom

    def ranges(self, k: int) -> np.ndarray:
        """The lidar's ranges (m, inf = none) at scan ``k``; people walk on by one scan period."""
        pose = self.truth[k]
        self.crowd.step(SCAN_PERIOD_S, k * SCAN_PERIOD_S, pose, ROBOT_RADIUS_M)
        true = self.lidar.true_ranges(pose, self.crowd.legs(), self._no_boxes)
        self._count_seen(pose, true)
        return self.lidar.measure(true)

    def _count_seen(self, pose: Pose, true: np.ndarray) -> None:
        lx, ly, lth = self.lidar.pose(pose)
        hit = np.isfinite(true) & (true <= self.spec.range_max_m)
        a = lth + self.spec.angles()[hit]
        r = true[hit] + SEEN_HIT_OFFSET_M
        g = self.grid
        cols = np.floor((lx + r * np.cos(a) - g.origin.x) / g.resolution).astype(np.int64)
        rows = np.floor((ly + r * np.sin(a) - g.origin.y) / g.resolution).astype(np.int64)
        ok = (rows >= 0) & (rows < g.data.shape[0]) & (cols >= 0) & (cols < g.data.shape[1])
        np.add.at(self.seen, (rows[ok], cols[ok]), 1)
