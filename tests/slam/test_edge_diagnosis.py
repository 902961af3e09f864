"""scripts/slam_edge_diagnosis.py: the edge errors it reports and the true measurements it
swaps in are the ones the pose graph sees."""

from __future__ import annotations

import math
from types import ModuleType

import numpy as np

from sage_robot.core.geometry import relative
from sage_robot.nav.slam.engine import Slam, SlamConfig
from sage_robot.nav.slam.posegraph import KIND_SCAN, PoseGraph
from tests.slam.scripts import load_script
from tests.slam.synth import corridor_loop, loop_path, simulate

SCAN_PERIOD_S = 0.2  # the drawn drive's scans


def load() -> ModuleType:
    return load_script("slam_edge_diagnosis")


def test_the_error_is_the_one_the_graph_weighs() -> None:
    diag = load()
    g = PoseGraph()
    g.add_node((0.0, 0.0, 0.3))
    g.add_node((1.0, 0.5, 1.2))
    z = (0.9, 0.7, 0.85)
    info = np.diag([4.0, 9.0, 25.0])
    g.add_edge(0, 1, z, info, KIND_SCAN)
    truth = g.poses
    err = diag.error_at(z, relative(truth[0], truth[1]))
    chi = float(np.sqrt(err @ info @ err))
    assert math.isclose(chi, float(g.edge_errors()[0]), rel_tol=1e-9)


def test_a_true_component_swapped_in_leaves_the_others() -> None:
    diag = load()
    zt = (1.0, 0.2, 0.4)
    z = (1.05, 0.17, 0.43)
    before = diag.components(diag.error_at(z, zt), diag.travel_axis(z))
    for k, part in enumerate(diag.COMPONENTS):
        edge = _Edge(z)
        fixed = diag.with_true(part)(edge, zt)
        # split on the travel axis of the measurement it replaced
        after = diag.components(diag.error_at(fixed, zt), diag.travel_axis(z))
        assert abs(after[k]) < 1e-12
        assert all(math.isclose(after[o], before[o], abs_tol=1e-12) for o in range(3) if o != k)
    assert np.allclose(diag.with_true(None)(_Edge(z), zt), zt)


def test_the_information_turns_with_the_heading() -> None:
    diag = load()
    corridor_north = np.diag([1e4, 1.0, 1e5])  # map frame: pinned east-west, free north-south
    turned = diag.in_edge_frame(corridor_north, math.pi / 2)  # driving north: x is forward
    assert np.allclose(np.diag(turned), [1.0, 1e4, 1e5])


class _Edge:
    def __init__(self, z: tuple[float, float, float]) -> None:
        self.z = z


def test_with_every_scan_edge_true_only_the_odometry_is_left() -> None:
    """The floor: every step and submap edge measuring the true relative pose leaves only
    what the odometry edges pull (here little: the drawn corridor's niches pin every scan),
    however wrong the scan edges were; its scale error is the odometry edges' length over
    the truth's."""
    diag = load()
    truth = loop_path(step_m=0.2)[:60]
    drive = simulate(corridor_loop(), truth)
    slam = Slam(SlamConfig(submap_edge_strides=(4, 8)), initial_pose=truth[0])
    for k in range(len(truth)):
        slam.add_scan(SCAN_PERIOD_S * k, drive.odom[k], drive.scans[k])
    for e in slam.graph.edges:  # every scan edge reads 1 % long
        if e.kind == KIND_SCAN:
            e.z = (e.z[0] * 1.01, e.z[1] * 1.01, e.z[2])
    slam.graph.optimize(iterations=50)
    truth_kf = [truth[round(kf.stamp / SCAN_PERIOD_S)] for kf in slam.keyframes]
    out = diag.floor(slam, truth_kf, truth)
    assert diag.trajectory_error(slam, slam.graph.poses, truth) > 0.02
    assert out["scans_true"] < 0.005
    assert out["scans_true_odom_scaled"] < 0.005
    odo = [e for e in slam.graph.edges if e.kind == "odom"]
    length = sum(math.hypot(e.z[0], e.z[1]) for e in odo)
    true_length = sum(math.dist(truth_kf[e.i][:2], truth_kf[e.j][:2]) for e in odo)
    assert math.isclose(out["odom_scale_error_pct"], (length / true_length - 1) * 100, abs_tol=1e-3)
