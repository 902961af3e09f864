"""Loop closures on a drawn square corridor: scans ray-cast on the true grid, drifting odometry."""

from __future__ import annotations

import itertools
import math
from dataclasses import replace

import numpy as np
import pytest

from sage_robot.core.geometry import compose, relative
from sage_robot.nav.slam.engine import Slam, SlamConfig
from sage_robot.nav.slam.posegraph import KIND_LOOP, PoseGraph

from .synth import corridor_loop, loop_path, simulate

STEP_M = 0.35  # travel between scans (m)


def run(config: SlamConfig, yaw_drift: float) -> tuple[Slam, np.ndarray, np.ndarray]:
    grid = corridor_loop()
    truth = loop_path(step_m=STEP_M)
    drive = simulate(grid, truth, yaw_drift=yaw_drift)
    slam = Slam(config, initial_pose=truth[0])
    for k, (odom, scan) in enumerate(zip(drive.odom, drive.scans, strict=True)):
        slam.add_scan(STEP_M * k, odom, scan)
    _, poses = slam.trajectory_array()
    return slam, poses, np.array(drive.odom)


def errors(poses: np.ndarray, truth: list[tuple[float, float, float]]) -> np.ndarray:
    t = np.array(truth)
    return np.hypot(poses[:, 0] - t[:, 0], poses[:, 1] - t[:, 1])


def test_loop_closure_corrects_accumulated_drift() -> None:
    """Tracking off (every match distrusted, as in a featureless stretch): the pose follows the
    drifting odometry until the robot is back at the start, where loop closures pull it home."""
    truth = loop_path(step_m=STEP_M)
    slam, poses, odom = run(replace(SlamConfig(), min_track_inliers=1.01), yaw_drift=0.002)
    drift = errors(odom, truth)
    assert drift[-1] > 0.8  # the odometry ends far from the truth
    assert slam.loop_closures >= 3
    err = errors(poses, truth)
    assert err[-1] < 0.25 * drift[-1]
    assert err[-1] < 0.2
    # loop edges were accepted between the start and the end of the lap
    loops = [e for e in slam.graph.edges if e.kind == KIND_LOOP]
    assert all(e.j - e.i > 50 for e in loops)


def test_scan_matching_keeps_drift_small_and_closes_the_loop() -> None:
    truth = loop_path(step_m=STEP_M)
    slam, poses, odom = run(SlamConfig(), yaw_drift=0.02)
    assert errors(odom, truth)[-1] > 3.0
    assert slam.loop_closures >= 1
    assert errors(poses, truth).max() < 0.08


def test_pose_graph_spreads_a_loop_error() -> None:
    rng = np.random.default_rng(0)
    truth = [(0.0, 0.0, 0.0)]
    for k in range(40):
        truth.append(compose(truth[-1], (1.0, 0.0, math.pi / 2 if k % 10 == 9 else 0.0)))
    est = [truth[0]]
    for a, b in itertools.pairwise(truth):
        dx, dy, dth = relative(a, b)
        est.append(compose(est[-1], (dx + rng.normal(0, 0.02), dy + rng.normal(0, 0.02), dth + 0.01)))
    graph = PoseGraph()
    for p in est:
        graph.add_node(p)
    for k in range(1, len(est)):
        graph.add_edge(k - 1, k, relative(est[k - 1], est[k]), np.diag([100.0, 100.0, 400.0]), "odom")
    graph.add_edge(0, 40, (0.0, 0.0, 0.0), np.diag([1e4, 1e4, 1e4]), KIND_LOOP)
    before = math.dist(est[40][:2], truth[40][:2])
    stats = graph.optimize()
    assert stats["final_cost"] < stats["initial_cost"]
    assert before > 0.5
    assert math.dist(graph.poses[40][:2], truth[40][:2]) < 0.02
    assert graph.poses[0] == pytest.approx(est[0], abs=1e-6)  # node 0 is the fixed anchor
    with pytest.raises(ValueError, match="two different existing nodes"):
        graph.add_edge(0, 99, (0.0, 0.0, 0.0), np.eye(3))
