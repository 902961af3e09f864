"""What the pose graph is made of: the scan-to-submap edges hold the chain straight, and the
keyframes the tracker alone placed are optimised when the drive ends."""

from __future__ import annotations

import math

import numpy as np

from sage_robot.core.geometry import relative
from sage_robot.nav.slam.engine import Slam, SlamConfig
from sage_robot.nav.slam.posegraph import KIND_ODOM, KIND_SCAN

from .synth import corridor_loop, loop_path, simulate

SCANS = 60  # 12 m along the drawn corridor: no loop to close yet


def _drive(config: SlamConfig, scans: int = SCANS, gyro: bool = False) -> Slam:
    truth = loop_path(step_m=0.2)[:scans]
    drive = simulate(corridor_loop(), truth)
    slam = Slam(config, initial_pose=truth[0])
    for k in range(len(truth)):
        slam.add_scan(0.2 * k, drive.odom[k], drive.scans[k], gyro=gyro)
    return slam


def test_submap_edges_hold_the_chain_straight_but_leave_its_length_to_the_step_edges() -> None:
    """A submap edge's translation along the travel is the chain's own (the local map's
    keyframes were placed by the same tracker): it carries no information there, and all of
    the match's across the travel and in heading."""
    slam = _drive(SlamConfig(submap_edge_strides=(4, 8)))
    submap = [e for e in slam.graph.edges if e.kind == KIND_SCAN and e.j - e.i > 1]
    steps = [e for e in slam.graph.edges if e.kind == KIND_SCAN and e.j - e.i == 1]
    assert len(submap) > 20
    for e in submap:
        dist = math.hypot(e.z[0], e.z[1])
        along = np.array([e.z[0] / dist, e.z[1] / dist, 0.0])
        across = np.array([-e.z[1] / dist, e.z[0] / dist, 0.0])
        assert along @ e.information @ along < 1e-9 * np.trace(e.information)
        assert across @ e.information @ across > 0.0
        assert e.information[2, 2] > 0.0
    # the step edges keep the match's information in every direction
    assert all(np.linalg.eigvalsh(e.information[:2, :2])[0] > 0.0 for e in steps[1:])


def test_the_keyframes_since_the_last_optimisation_are_optimised_when_the_drive_ends() -> None:
    slam = _drive(SlamConfig(submap_edge_strides=(4, 8)))
    assert slam.loop_closures == 0
    assert slam.optimizations == 0
    assert slam.pending_keyframes == len(slam.keyframes) - 1  # all but the first
    cost_before = float((slam.graph.edge_errors() ** 2).sum())
    version = slam.map_version
    slam.finish()
    assert slam.optimizations == 1
    assert slam.pending_keyframes == 0
    assert slam.map_version == version + 1  # the grid is redrawn at the optimised poses
    assert float((slam.graph.edge_errors() ** 2).sum()) < cost_before
    slam.finish()  # nothing new: nothing to do
    assert slam.optimizations == 1


def test_gyro_turned_odometry_edges_are_measured_again_with_the_calibration_learnt_so_far() -> None:
    """The first metres are driven before the odometry's calibration is known: when the graph
    is optimised, every gyro-turned odometry edge is measured again from its raw step with the
    calibration learnt by then (a 2 % scale error is 16 cm over the first 8 m)."""
    slam = _drive(SlamConfig(calibrate_odometry=True), scans=100, gyro=True)
    cal = slam.odometry_calibration
    assert cal.calibrated
    odometry = [e for e in slam.graph.edges if e.kind == KIND_ODOM]
    raw = [relative(slam.keyframes[e.i].odom, slam.keyframes[e.j].odom) for e in odometry]
    stale = sum(not np.allclose(e.z, cal.correct(r), atol=1e-12) for e, r in zip(odometry, raw, strict=True))
    assert stale > 0  # measured with the calibration of their time (or none yet)
    slam.finish()
    for e, r in zip(odometry, raw, strict=True):
        assert np.allclose(e.z, cal.correct(r), atol=1e-12)


def test_wheel_turned_odometry_edges_keep_the_calibration_of_their_time() -> None:
    slam = _drive(SlamConfig(calibrate_odometry=True), scans=100)
    assert slam.odometry_calibration.calibrated
    before = [e.z for e in slam.graph.edges if e.kind == KIND_ODOM]
    slam.finish()
    assert [e.z for e in slam.graph.edges if e.kind == KIND_ODOM] == before
