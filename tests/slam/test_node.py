"""The slam node on a bus: scans + odometry in, progress and a growing /map out, save service."""

from __future__ import annotations

import asyncio
import math
from pathlib import Path

import numpy as np
import pytest

from sage_robot.app.profiles import PROFILES
from sage_robot.core import topics
from sage_robot.core.bus import Bus
from sage_robot.core.clock import SimClock
from sage_robot.core.config import load_profile
from sage_robot.core.errors import ServiceError
from sage_robot.core.mapio import read_map
from sage_robot.core.msgs import OccupancyGrid
from sage_robot.core.node import NodeContext
from sage_robot.nav.slam.messages import SaveMapReply, SaveMapRequest, SlamProgress
from sage_robot.nav.slam.node import (
    AUTOSAVE_RESOURCE,
    OUT_DIR_RESOURCE,
    SAVED_RESOURCE,
    SLAM_PROGRESS,
    SLAM_SAVE,
    SlamNode,
    odom_at,
    slam_config,
)

from .synth import corridor_loop, loop_path, publish_step, simulate

WAIT_S = 20.0  # bound on every wait (a loaded 2-core machine)
SCANS = 25


async def test_node_maps_publishes_and_saves(tmp_path: Path) -> None:
    settings = load_profile(None, {"robot": {"lidar": {"x_m": 0.0, "y_m": 0.0, "yaw_rad": 0.0}}})
    clock = SimClock()
    bus = Bus(clock)
    ctx = NodeContext(bus, clock, settings)
    ctx.resources[OUT_DIR_RESOURCE] = str(tmp_path / "maps")
    ctx.resources[AUTOSAVE_RESOURCE] = "on_exit"
    truth = loop_path(step_m=0.3)[:SCANS]
    drive = simulate(corridor_loop(), truth, yaw_drift=0.01)
    node = SlamNode(ctx)
    await node.setup()
    progress = bus.subscribe(SLAM_PROGRESS, SlamProgress, maxsize=100)
    maps = bus.subscribe(topics.MAP, OccupancyGrid, maxsize=10)
    try:
        last: SlamProgress | None = None
        for k in range(SCANS):
            await publish_step(bus, clock, drive, k)
            last = await asyncio.wait_for(progress.get(), WAIT_S)
        assert last is not None
        assert last.scans == SCANS
        assert last.keyframes >= SCANS // 2
        assert last.match_score > 0.5
        # The estimate follows the truth (map frame = the first pose, here the origin).
        assert np.hypot(last.pose.x - truth[-1][0], last.pose.y - truth[-1][1]) < 0.1
        await clock.step(1.0)
        now = clock.now()
        grid = await asyncio.wait_for(maps.get(), WAIT_S)
        while grid.stamp < now - 1e-6:  # maps published while driving, then the final one
            grid = await asyncio.wait_for(maps.get(), WAIT_S)
        assert (grid.data == 100).sum() > 500
        assert (grid.data == 0).sum() > 2000
        assert bus.latest(topics.MAP) is grid  # latched for late subscribers

        assert node.slam.pending_keyframes > 0  # the keyframes since the last loop closure...
        reply = await bus.call(SLAM_SAVE, SaveMapRequest("demand", str(tmp_path / "other")), timeout=WAIT_S)
        assert isinstance(reply, SaveMapReply)
        assert node.slam.pending_keyframes == 0  # ...are optimised with the rest before saving
        assert files_exist(reply.graph)
        saved = read_map(reply.yaml)
        assert (saved.data == 100).sum() > 500
        # the handler's ConfigError comes back as a ServiceError
        with pytest.raises(ServiceError, match="use letters"):
            await bus.call(SLAM_SAVE, SaveMapRequest("../x"), timeout=WAIT_S)
    finally:
        await node.teardown()
        await node._close()
    paths = ctx.resources[SAVED_RESOURCE]
    assert Path(paths["yaml"]).parent == tmp_path / "maps"
    assert files_exist(paths["pgm"])


def files_exist(*paths: str) -> bool:
    """Whether every file was written (a plain call: the node has finished writing them)."""
    return all(Path(p).exists() for p in paths)


def test_sim_slam_profile() -> None:
    names = [n for n, _ in PROFILES["sim_slam"]]
    # Mapping mode: world, firmware model, odometry bridge, web (teleop, growing map, save),
    # Foxglove, liveness and battery alerts, SLAM; no map-based nodes, no tour guide.
    assert set(names) == {
        "sim_world", "mcu_sim", "serial_bridge", "web", "foxglove", "heartbeat", "battery_watchdog", "slam"
    }
    assert set(names) - {"slam"} <= {n for n, _ in PROFILES["sim"]}
    assert "slam" in [n for n, _ in PROFILES["slam"]]


def test_the_robot_maps_with_the_settings_the_simulation_bench_measures() -> None:
    """The shipped profile's lidar (an A1M8, 1 % range noise) gets the low-cost lidar settings
    that ``sage bench slam --sim`` scores; ``range_noise_fraction: 0`` the engine's defaults."""
    from sage_robot.bench.slam_sim import slam_config as bench_config
    from sage_robot.nav.slam.engine import SlamConfig
    from sage_robot.sim.lidar import LidarSpec

    robot = slam_config(load_profile().slam)
    bench = bench_config(LidarSpec())
    assert robot.match == bench.match
    assert robot.match.range_noise_fraction == 0.01
    for key in ("submap_edge_strides", "calibrate_odometry", "oriented_normals", "map_min_support",
                "map_normal_neighbours", "drop_small_objects_m"):
        assert getattr(robot, key) == getattr(bench, key), key
    survey = slam_config(load_profile(overrides={"slam": {"range_noise_fraction": 0}}).slam)
    assert survey.match == SlamConfig().match
    assert survey.submap_edge_strides == ()
    assert not survey.calibrate_odometry


def test_odometry_is_interpolated_at_the_scan_time() -> None:
    history = [(1.0, (0.0, 0.0, 3.0)), (1.1, (0.1, 0.0, -3.0)), (1.2, (0.2, 0.1, -2.9))]
    x, y, th = odom_at(history, 1.05)
    assert x == pytest.approx(0.05)
    assert y == 0.0
    assert abs(th) == pytest.approx(math.pi, abs=1e-9)  # halfway across the ±pi seam
    assert odom_at(history, 0.5) == history[0][1]
    assert odom_at(history, 2.0) == history[-1][1]


async def test_node_turns_the_odometry_with_the_gyro() -> None:
    """With ``/imu/data`` the odometry's turns are the gyro's: scans that see nothing (the pose
    is dead-reckoned) follow the gyro's heading, not the wheels' 20 % too large turn; when the
    gyro falls silent the node goes on with the wheels' turns."""
    from sage_robot.core.msgs import Imu, LaserScan, Odometry, Pose2D, Twist

    settings = load_profile(None, {"robot": {"lidar": {"x_m": 0.0, "y_m": 0.0, "yaw_rad": 0.0}}})
    clock = SimClock()
    bus = Bus(clock)
    node = SlamNode(NodeContext(bus, clock, settings))
    await node.setup()
    progress = bus.subscribe(SLAM_PROGRESS, SlamProgress, maxsize=100)
    rate, wheels_scale, scan_s, imu_s = 0.5, 1.2, 0.2, 0.01
    nothing = np.full(360, np.inf, dtype=np.float32)
    heading = 0.0  # the wheels'

    async def scan_step(with_gyro: bool) -> SlamProgress:
        nonlocal heading
        for _ in range(round(scan_s / imu_s)):
            await clock.step(imu_s)
            heading += rate * wheels_scale * imu_s
            if with_gyro:
                bus.publish(topics.IMU, Imu(clock.now(), (0.0, 0.0, rate), (0.0, 0.0, 9.81)))
        bus.publish(topics.ODOM, Odometry(clock.now(), Pose2D(0.0, 0.0, heading), Twist()))
        await asyncio.sleep(0)
        bus.publish(topics.SCAN, LaserScan(clock.now(), "laser", -math.pi, math.pi / 180, 0.1, 12.0, nothing))
        return await asyncio.wait_for(progress.get(), WAIT_S)

    try:
        for _ in range(6):
            last = await scan_step(True)
        assert node.gyro_scans == 5  # every step after the first scan
        assert last.pose.theta == pytest.approx(5 * rate * scan_s, abs=1e-6)
        for _ in range(3):
            last = await scan_step(False)
        assert node.gyro_scans == 5
        turned = 5 * rate * scan_s + 3 * rate * wheels_scale * scan_s
        assert last.pose.theta == pytest.approx(turned, abs=1e-6)
    finally:
        await node.teardown()
        await node._close()


async def test_the_grid_is_redrawn_after_an_optimisation_at_most_every_rebuild_period() -> None:
    """New map scans are drawn at each publish; an optimisation's redraw of every scan waits for
    ``map_rebuild_period_s`` since the last one, except for a save; a drawing job that a save
    overtook is dropped (no scan drawn twice). The node's own map timer is kept out of the way
    (it would draw into the same grid from a worker thread)."""
    settings = load_profile(
        None,
        {"robot": {"lidar": {"x_m": 0.0, "y_m": 0.0, "yaw_rad": 0.0}}, "slam": {"map_period_s": 1e6}},
    )
    clock = SimClock()
    node = SlamNode(NodeContext(Bus(clock), clock, settings))
    await node.setup()
    period = node.config.map_rebuild_period_s
    truth = loop_path(step_m=0.1)[:30]
    drive = simulate(corridor_loop(), truth, yaw_drift=0.01)
    try:
        for k in range(15):
            node._process(0.1 * k, drive.odom[k], drive.scans[k], False)
        job = node._map_job(full=False)
        assert job is not None
        assert not job.rebuild
        assert (job.start, job.count) == (0, node.slam.map_scan_count)
        node._draw(job)
        assert node._map_job(full=False) is None  # nothing new
        node.slam.optimize()  # the graph moved: a redraw, the first one at once
        job = node._map_job(full=False)
        assert job is not None
        assert job.rebuild
        node._draw(job)
        for k in range(15, 30):
            node._process(0.1 * k, drive.odom[k], drive.scans[k], False)
        node.slam.optimize()
        await clock.step(0.5 * period)
        job = node._map_job(full=False)  # too soon for another redraw: the new scans only
        assert job is not None
        assert not job.rebuild
        assert job.start > 0
        saved = node._map_job(full=True)  # a save redraws, whatever the period
        assert saved is not None
        assert saved.rebuild
        node._draw(saved)
        before = node.mapper.logodds.copy()
        node._draw(job)  # overtaken: the save drew these scans already
        assert np.array_equal(node.mapper.logodds, before)
        await clock.step(period)
        node.slam.optimize()
        job = node._map_job(full=False)
        assert job is not None
        assert job.rebuild
    finally:
        await node.teardown()
        await node._close()
