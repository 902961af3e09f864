"""The parts of the corridor fix and of the simulation scores, each on a small drawn case."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from sage_robot.core.geometry import compose
from sage_robot.nav.slam.dynamic import small_foreground, supported
from sage_robot.nav.slam.mapscore import score_map, wall_distance
from sage_robot.nav.slam.matcher import MatchConfig, PointMap
from sage_robot.nav.slam.odomcal import OdometryCalibration
from sage_robot.sim.raycast import ray_circles
from tests.support.grids import room

STEP_M = 0.1


def test_a_perfect_map_scores_zero_and_a_shifted_one_does_not() -> None:
    truth = room(6.0, 4.0, wall_cells=2)
    seen = truth.data == 100
    perfect = score_map(truth, truth, seen)
    assert perfect.wall_distance_mean_m == 0.0
    assert perfect.walls_found == 1.0
    assert perfect.precision == 1.0
    shifted = dataclasses.replace(truth, origin=dataclasses.replace(truth.origin, x=truth.origin.x + 0.3))
    off = score_map(truth, shifted, seen)
    assert off.wall_distance_mean_m > 0.05
    assert off.walls_found < 0.95


def test_a_return_just_behind_a_wall_on_the_maps_edge_is_as_near_as_one_in_front() -> None:
    truth = room(6.0, 4.0, wall_cells=2)  # the walls are the grid's outermost cells
    x0, res = truth.origin.x, truth.resolution
    y = truth.origin.y + 2.0
    near = wall_distance(truth, np.array([[x0 + 2 * res + 0.05, y], [x0 - 0.05, y], [x0 - 3.0, y]]))
    assert np.allclose(near[:2], 0.05)
    assert np.isinf(near[2])  # farther off the grid than FAR_M: as far as it gets


def test_legs_in_front_of_a_wall_are_small_foreground_and_the_wall_is_not() -> None:
    angles = -math.pi + 2 * math.pi * np.arange(360) / 360
    walls = np.full(360, 5.0)  # a round room, 5 m all around
    legs = np.array([[2.0, 0.11, 0.07], [2.0, -0.11, 0.07]])
    ranges = np.minimum(walls, ray_circles(0.0, 0.0, angles, legs))
    hits = np.isfinite(ranges)
    small = small_foreground(ranges, angles, hits, 0.25)
    assert small.any()
    assert np.array_equal(small, ranges < 4.0)  # exactly the beams that hit a leg
    assert not small_foreground(walls, angles, hits, 0.25).any()


def test_odometry_scale_and_heading_drift_are_learnt_where_the_scans_pin_the_pose() -> None:
    cal = OdometryCalibration()
    pose = odom = (0.0, 0.0, 0.0)
    everywhere = np.diag([1e4, 1e4, 1e5])
    true_step = (STEP_M, 0.0, 0.0)
    odom_step = (STEP_M * 1.02, 0.0, 0.01 * STEP_M)  # 2 % long, 0.01 rad/m heading drift
    for _ in range(200):
        pose, odom = compose(pose, true_step), compose(odom, odom_step)
        cal.observe(pose, odom, everywhere)
    assert cal.calibrated
    assert abs(cal.scale - 1 / 1.02) < 0.002
    assert abs(cal.yaw_per_m - 0.01) < 0.001
    corrected = cal.correct(odom_step)
    assert abs(corrected[0] - STEP_M) < 0.0005
    assert abs(corrected[2]) < 0.0002


def test_the_turn_scale_is_learnt_from_turns_between_matched_scans() -> None:
    """Turns on the spot (0.2 rad a scan) read 2 % too much; after 3 rad of comparison the
    calibration scales them back, also across the ±pi seam and for turns either way."""
    cal = OdometryCalibration()
    pose = odom = (0.0, 0.0, 0.0)
    everywhere = np.diag([1e4, 1e4, 1e5])
    for k in range(60):
        turn = 0.2 if (k // 20) % 2 == 0 else -0.2  # a full turn left, then right, then left
        pose, odom = compose(pose, (0.0, 0.0, turn)), compose(odom, (0.0, 0.0, turn * 1.02))
        cal.observe(pose, odom, everywhere)
        if k == 10:
            assert not cal.turn_calibrated  # 2 rad compared: not yet
            assert cal.correct((0.0, 0.0, 0.2)) == (0.0, 0.0, 0.2)
    assert cal.turn_calibrated
    assert abs(cal.turn_scale - 1 / 1.02) < 0.002
    assert abs(cal.correct((0.0, 0.0, 0.204))[2] - 0.2) < 0.0005
    # an unmatched scan ends the turn being compared: nothing learnt from it
    before = cal.turn_scale
    for _ in range(10):
        odom = compose(odom, (0.0, 0.0, 0.3))
        cal.observe(pose, odom, None)
    assert cal.turn_scale == before


def test_a_corridor_match_teaches_the_odometry_nothing() -> None:
    cal = OdometryCalibration()
    pose = odom = (0.0, 0.0, 0.0)
    across_only = np.diag([1.0, 1e4, 1e5])  # a bare corridor along x
    for _ in range(200):
        pose, odom = compose(pose, (STEP_M, 0.0, 0.0)), compose(odom, (STEP_M * 1.02, 0.0, 0.0))
        cal.observe(pose, odom, across_only)
    assert not cal.calibrated
    assert cal.correct((STEP_M, 0.0, 0.0)) == (STEP_M, 0.0, 0.0)


def test_a_loop_closure_moving_the_map_is_not_read_as_travel() -> None:
    """Every 25 scans the map (and with it the tracked pose) is corrected by 0.3 m and 0.05 rad,
    as a loop closure does; the stretches open across it move with the map, so the scale and
    the turn scale stay the odometry's true ones."""
    kept, dropped = OdometryCalibration(), OdometryCalibration()
    pose = odom = (0.0, 0.0, 0.0)
    everywhere = np.diag([1e4, 1e4, 1e5])
    correction = (0.3, -0.2, 0.05)
    for k in range(600):  # 30 m straight, then turns on the spot
        step = (STEP_M, 0.0, 0.0) if k < 300 else (0.0, 0.0, 0.2)
        pose, odom = compose(pose, step), compose(odom, (step[0] * 1.02, 0.0, step[2] * 1.02))
        if k % 25 == 24:
            before, pose = pose, compose(correction, pose)
            kept.moved(before, pose)
        kept.observe(pose, odom, everywhere)
        dropped.observe(pose, odom, everywhere)
    assert abs(kept.scale - 1 / 1.02) < 0.001
    assert abs(kept.turn_scale - 1 / 1.02) < 0.001
    # without it: the corrections read as travel and turn
    assert abs(dropped.scale - 1 / 1.02) > 0.01
    assert abs(dropped.turn_scale - 1 / 1.02) > 0.01


def test_a_tracker_that_jumped_teaches_the_odometry_nothing() -> None:
    """Three times the tracked pose slides 0.2 m along the travel (a weak match in a corridor):
    those stretches disagree with the calibrated odometry and are left out."""
    cal = OdometryCalibration()
    pose = odom = (0.0, 0.0, 0.0)
    everywhere = np.diag([1e4, 1e4, 1e5])
    for k in range(600):
        pose, odom = compose(pose, (STEP_M, 0.0, 0.0)), compose(odom, (STEP_M * 1.02, 0.0, 0.0))
        if k in (250, 400, 550):  # once 20 m have been compared
            pose = compose(pose, (0.2, 0.0, 0.0))
        cal.observe(pose, odom, everywhere)
    assert cal.outliers == 3
    assert abs(cal.scale - 1 / 1.02) < 0.0005  # each jump would have been 0.3 % of the 60 m


def test_odometry_that_changed_is_learnt_again() -> None:
    """After 30 m the odometry reads 6 % long instead of 2 % (another tyre): every stretch
    disagrees, and after a few the calibration starts again from the new odometry."""
    cal = OdometryCalibration()
    pose = odom = (0.0, 0.0, 0.0)
    everywhere = np.diag([1e4, 1e4, 1e5])
    for k in range(600):
        long = 1.02 if k < 300 else 1.06
        pose, odom = compose(pose, (STEP_M, 0.0, 0.0)), compose(odom, (STEP_M * long, 0.0, 0.0))
        cal.observe(pose, odom, everywhere)
        if k == 299:
            assert abs(cal.scale - 1 / 1.02) < 0.0005
    assert cal.outliers >= 1
    assert abs(cal.scale - 1 / 1.06) < 0.0005


def test_the_far_face_of_a_thin_wall_is_not_taken_for_the_near_one() -> None:
    ys = np.arange(-2.0, 2.0, 0.03)
    west_face = np.column_stack((np.zeros_like(ys), ys))  # mapped from the west: faces -x
    facing_west = np.tile([-1.0, 0.0], (len(ys), 1))
    # From (2, 0) the robot sees the wall's east face, 0.2 m further east.
    scan = np.column_stack((np.full_like(ys, 0.2 - 2.0), ys))
    oriented = PointMap(west_face, MatchConfig(), 1.0, facing_west, oriented=True)
    assert oriented.refine(scan, (2.0, 0.0, 0.0)).inliers == 0.0
    naive = PointMap(west_face, MatchConfig(), 1.0, facing_west)
    fooled = naive.refine(scan, (2.0, 0.0, 0.0))
    assert fooled.inliers > 0.9
    assert abs(fooled.pose[0] - 1.8) < 0.01


def test_points_only_one_keyframe_saw_drop_out_of_the_local_map() -> None:
    wall = np.column_stack((np.linspace(0.0, 1.0, 11), np.zeros(11)))
    leg_then, leg_now = np.array([[0.5, 1.0]]), np.array([[0.9, 1.0]])
    pts = np.concatenate((wall, leg_then, wall + 0.01, leg_now))
    owner = np.repeat([0, 0, 1, 1], [11, 1, 11, 1])
    kept = supported(pts, owner, 0.15, 2)
    assert kept[:11].all()
    assert kept[12:23].all()
    assert not kept[11]
    assert not kept[23]


def _walls(*segments: tuple[float, float, float, float]) -> np.ndarray:
    """Points every 3 cm along the segments (x0, y0, x1, y1), m."""
    out = []
    for x0, y0, x1, y1 in segments:
        n = max(2, round(math.hypot(x1 - x0, y1 - y0) / 0.03))
        t = np.linspace(0.0, 1.0, n)
        out.append(np.column_stack((x0 + t * (x1 - x0), y0 + t * (y1 - y0))))
    return np.concatenate(out)


def _three_matches(walls: np.ndarray, near: np.ndarray, shift: tuple[float, float], at: tuple[float, float]):
    """The pose the range-weighted, the adaptive and the equal-weighted matcher find for a
    scan from ``at`` of ``walls`` whose ``near`` points read ``shift`` (m) off."""
    scan = walls - np.array(at) + np.where(near[:, None], np.array(shift), 0.0)
    plain = MatchConfig(range_noise_fraction=0.01)
    configs = (plain, dataclasses.replace(plain, equal_weights_isotropy=0.25), MatchConfig())
    truth = (at[0], at[1], 0.0)
    return [np.array(PointMap(walls, cfg, 1.0).refine(scan, truth).pose[:2]) for cfg in configs]


def test_where_the_scan_pins_the_pose_every_pairing_weighs_the_same() -> None:
    # A 6 x 4 m room seen from 1 m off its west wall, which reads 5 mm long: the range weights
    # let that near wall decide the match; the room pins the pose, so the adaptive matcher
    # weighs it like the far east wall.
    walls = _walls((0, 0, 6, 0), (6, 0, 6, 4), (6, 4, 0, 4), (0, 4, 0, 0))
    plain, adaptive, equal = _three_matches(walls, walls[:, 0] < 0.01, (-0.005, 0.0), (1.0, 2.0))
    assert abs(plain[0] - 1.0) > 0.003
    assert abs(equal[0] - 1.0) < abs(plain[0] - 1.0) - 0.001
    assert np.allclose(adaptive, equal, atol=2e-4), (adaptive, equal)


def test_along_a_bare_corridor_the_range_weights_stay() -> None:
    # Two walls 2 m apart, 20 m long, the near one reading 5 mm off: the match pins nothing
    # along the corridor, and far returns must not pull it, so the range weights stay.
    walls = _walls((-10, 0, 10, 0), (-10, 2, 10, 2))
    near = (walls[:, 1] < 0.01) & (np.abs(walls[:, 0]) < 3.0)
    plain, adaptive, equal = _three_matches(walls, near, (0.0, 0.005), (0.0, 0.5))
    assert np.array_equal(adaptive, plain)
    assert abs(plain[1] - equal[1]) > 0.001
