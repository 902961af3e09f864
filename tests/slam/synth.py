"""A drawn world for SLAM tests: a square corridor loop with door niches, lidar scans by ray
casting the true grid, and wheel odometry that drifts.

Map frame: metres, x right, y up; the loop's corridor centre line is a square of side
``SIDE_M`` from (0, 0).
"""

from __future__ import annotations

import asyncio
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from sage_robot.core import topics
from sage_robot.core.geometry import compose, relative
from sage_robot.core.msgs import LaserScan, OccupancyGrid, Odometry, Pose2D, Twist
from sage_robot.nav.slam.points import Scan
from sage_robot.sim.raycast import GridRaycaster

from ..support.grids import FREE, WALL, blank, fill

RES_M = 0.05
SIDE_M = 12.0  # corridor centre line: a square of this side
HALF_WIDTH_M = 1.0  # corridor half width
MARGIN_M = 3.0
BEAMS = 360
RANGE_MAX_M = 12.0
RANGE_NOISE_M = 0.01


def corridor_loop(seed: int = 3) -> OccupancyGrid:
    """Walls everywhere, a square corridor carved out, niches and pillars for features."""
    rng = np.random.default_rng(seed)
    size = int((SIDE_M + 2 * MARGIN_M) / RES_M)
    grid = blank(size, size, RES_M, (-MARGIN_M, -MARGIN_M), value=WALL)

    def carve(x0: float, y0: float, x1: float, y1: float, value: int = FREE) -> None:
        fill(grid, x0, y0, x1, y1, value)

    h = HALF_WIDTH_M
    carve(-h, -h, SIDE_M + h, h)
    carve(-h, SIDE_M - h, SIDE_M + h, SIDE_M + h)
    carve(-h, -h, h, SIDE_M + h)
    carve(SIDE_M - h, -h, SIDE_M + h, SIDE_M + h)
    for k in range(8):  # door niches of random depth along the walls, and pillars
        t = 1.5 + k * 1.2 + rng.uniform(0, 0.4)
        d = rng.uniform(0.3, 0.8)
        carve(t, h, t + 0.6, h + d)
        carve(SIDE_M - h - d, t, SIDE_M - h, t + 0.5)
        carve(t, SIDE_M + h, t + 0.7, SIDE_M + h + d * 0.8)
        carve(-h - d, t, -h, t + 0.6)
    for x, y in ((5.0, 0.4), (SIDE_M - 0.5, 8.0), (9.0, SIDE_M + 0.5), (-0.4, 6.0)):
        carve(x, y, x + 0.2, y + 0.2, WALL)
    return grid


def loop_path(step_m: float = 0.2, laps: float = 1.15) -> list[tuple[float, float, float]]:
    """Poses along the centre line, counter-clockwise from (0, 0), turning on the spot at corners."""
    poses = []
    corners = [(0.0, 0.0), (SIDE_M, 0.0), (SIDE_M, SIDE_M), (0.0, SIDE_M)]
    total = laps * 4 * SIDE_M
    s = 0.0
    while s <= total:
        side = int(s // SIDE_M) % 4
        t = s % SIDE_M
        (x0, y0), (x1, y1) = corners[side], corners[(side + 1) % 4]
        heading = math.atan2(y1 - y0, x1 - x0)
        poses.append((x0 + (x1 - x0) * t / SIDE_M, y0 + (y1 - y0) * t / SIDE_M, heading))
        s += step_m
        if t + step_m >= SIDE_M and s <= total:  # turn at the corner in a few steps
            for k in range(1, 4):
                cx, cy = corners[(side + 1) % 4]
                poses.append((cx, cy, heading + k * math.pi / 8))
    return poses


@dataclass
class Drive:
    truth: list[tuple[float, float, float]]
    odom: list[tuple[float, float, float]]
    scans: list[Scan]


def simulate(
    grid: OccupancyGrid, truth: list[tuple[float, float, float]], yaw_drift: float = 0.02, seed: int = 1
) -> Drive:
    """Scans at the true poses; odometry whose heading drifts ``yaw_drift`` rad per metre."""
    rng = np.random.default_rng(seed)
    caster = GridRaycaster(grid)
    angles = -math.pi + 2 * math.pi * np.arange(BEAMS) / BEAMS
    odom = [truth[0]]
    scans = []
    for k, pose in enumerate(truth):
        if k:
            dx, dy, dth = relative(truth[k - 1], pose)
            dist = math.hypot(dx, dy)
            noisy = (
                dx * (1 + rng.normal(0, 0.02)),
                dy + rng.normal(0, 0.005),
                dth * 1.03 + yaw_drift * dist + rng.normal(0, 0.003),
            )
            odom.append(compose(odom[-1], noisy))
        ranges = caster.cast(pose[0], pose[1], angles + pose[2], RANGE_MAX_M)
        ranges = ranges + rng.normal(0, RANGE_NOISE_M, BEAMS)
        scans.append(Scan(ranges.astype(np.float32), angles, 0.1, RANGE_MAX_M))
    return Drive(truth, odom, scans)


async def publish_step(bus: Any, clock: Any, drive: Drive, k: int, dt: float = 0.2) -> None:
    """Step the clock ``dt``, then publish odometry ``k`` and scan ``k`` of ``drive`` on the bus,
    as the robot's bridge and lidar do."""
    await clock.step(dt)
    x, y, th = drive.odom[k]
    bus.publish(topics.ODOM, Odometry(clock.now(), Pose2D(x, y, th), Twist()))
    await asyncio.sleep(0)
    scan = drive.scans[k]
    first, step = float(scan.angles[0]), float(scan.angles[1] - scan.angles[0])
    bus.publish(topics.SCAN, LaserScan(clock.now(), "laser", first, step, 0.1, 12.0, scan.ranges))
