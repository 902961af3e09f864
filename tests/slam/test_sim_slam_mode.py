"""SLAM mode on the real simulator: the world, the firmware model behind a pseudo-terminal, the
serial bridge and the slam node, driven by the bundled ``teleop_drive`` scenario (standing
/cmd_vel commands, two walkers) on the simulated clock."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from sage_robot.app.runtime import make_context, run_launcher, specs_for
from sage_robot.core import topics
from sage_robot.core.config import load_profile
from sage_robot.core.mapio import read_map
from sage_robot.core.msgs import Odometry
from sage_robot.nav.slam.node import (
    AUTOSAVE_RESOURCE,
    INITIAL_POSE_RESOURCE,
    OUT_DIR_RESOURCE,
    SAVED_RESOURCE,
)
from sage_robot.sim.node import SCENARIO_RESOURCE, WORLD_RESOURCE
from sage_robot.sim.raycast import GridRaycaster
from sage_robot.sim.scenario import bundled_scenarios, load_scenario

NODES = {"sim_world", "mcu_sim", "serial_bridge", "slam"}
DOCK = (47.3, 57.5, 0.0)  # DOCKING_STATION in the shipped waypoints: the scenario's start
SCAN_HZ = 10.0  # the simulated lidar's rate
ERR_MEAN_M, ERR_MAX_M = 0.08, 0.2  # bounds on the mapped poses' error against the truth (m)


IMU_CALIBRATION_S = 0.3  # the scenario drives off at 0.5 s: the bridge calibrates before


@pytest.mark.parametrize("imu", [False, True], ids=["wheels", "gyro"])
async def test_teleop_drive_in_slam_mode(tmp_path: Path, imu: bool) -> None:
    """With ``imu`` (``sage slam --imu``) the firmware's gyro frames reach the slam node
    through the bridge, and the odometry turns with them."""
    path = next(p for p in bundled_scenarios() if Path(p).stem == "teleop_drive")
    scenario = load_scenario(path)
    overrides = scenario.settings_overrides()
    if imu:
        imu_on = {"imu_enabled": True, "imu_calibration_s": IMU_CALIBRATION_S}
        overrides["mcu"] = {**overrides.get("mcu", {}), **imu_on}
    # As fast as possible, in lockstep: time waits for each scan's matching (clock.offload),
    # so every scan is mapped and the run does not depend on the machine's load.
    overrides.setdefault("sim", {})["speed"] = None
    settings = load_profile(None, overrides)
    ctx = make_context(settings, simulated=True)
    ctx.resources[SCENARIO_RESOURCE] = scenario
    ctx.resources[OUT_DIR_RESOURCE] = str(tmp_path)
    ctx.resources[AUTOSAVE_RESOURCE] = "teleop"
    ctx.resources[INITIAL_POSE_RESOURCE] = DOCK  # map frame = the building's frame
    specs = [s for s in specs_for("sim_slam") if s.name in NODES]
    assert {s.name for s in specs} == NODES
    truth: list[tuple[float, float, float, float]] = []  # stamp, x, y, theta in the map frame
    ctx.bus.subscribe(
        topics.SIM_TRUTH, Odometry, lambda m: truth.append((m.stamp, *m.pose.as_tuple())), maxsize=100_000
    )
    launcher = await run_launcher(ctx, specs, until=scenario.duration_s)
    assert not [n for n, h in launcher.health.items() if h.restarts], launcher.health
    stats = launcher.nodes["slam"].stats()
    if imu:  # every scan but those before the calibration ended
        assert stats["gyro_scans"] >= stats["scans"] - 5, stats
    else:
        assert stats["gyro_scans"] == 0, stats
    world = ctx.resources[WORLD_RESOURCE]
    truth_end = world.pose
    assert math.dist(truth_end[:2], DOCK[:2]) > 8.0  # it drove out and down the corridor

    saved = ctx.resources[SAVED_RESOURCE]
    traj = np.loadtxt(saved["trajectory"])
    assert scenario.duration_s is not None
    assert len(traj) >= SCAN_HZ * scenario.duration_s - 1  # lockstep: every scan is mapped
    # Each mapped scan's pose against the true pose at its stamp.
    true = np.array(truth)
    k = np.clip(np.searchsorted(true[:, 0], traj[:, 0]), 0, len(true) - 1)
    assert np.abs(true[k, 0] - traj[:, 0]).max() < 0.05
    err = np.hypot(traj[:, 1] - true[k, 1], traj[:, 2] - true[k, 2])
    # Every scan mapped: 3.4 cm mean and 8.4 cm worst here (wheels; 3.3 / 8.9 with the gyro),
    # bounded at about twice that.
    assert err.mean() < ERR_MEAN_M, (err.mean(), err.max())
    assert err.max() < ERR_MAX_M, (err.mean(), err.max())
    assert np.abs(np.remainder(traj[:, 3] - true[k, 3] + np.pi, 2 * np.pi) - np.pi).max() < 0.1
    grid = read_map(saved["yaml"])
    rows, cols = np.nonzero(grid.data == 100)
    xs = grid.origin.x + (cols + 0.5) * grid.resolution
    ys = grid.origin.y + (rows + 0.5) * grid.resolution
    walls = GridRaycaster(read_map(Path(world_map_path())))
    near = walls.clearance(xs, ys) <= 0.15
    assert len(xs) > 300
    assert near.mean() > 0.8  # walls where the building has walls


def world_map_path() -> str:
    from sage_robot.core.paths import package_data

    return str(package_data("maps", "campus", "map.yaml"))
