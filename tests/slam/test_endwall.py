"""The lidar's straight-ahead range as a ruler for the odometry's scale (``nav/slam/endwall``),
and the calibration taking its readings."""

from __future__ import annotations

import math

import numpy as np

from sage_robot.core.geometry import compose
from sage_robot.nav.slam.endwall import MAX_RANGE_M, MAX_SCANS, EndWallRuler, fit_wall, straight_range
from sage_robot.nav.slam.odomcal import GATE_AFTER_M, OdometryCalibration
from sage_robot.nav.slam.points import Scan

STEP_M = 0.1
ODOM_LONG = 1.02  # the wheels read 2 % long
NOISE_FRACTION = 0.01  # the lidar's range noise
BEAMS = 360


def _scan(ahead_m: float, behind_m: float, rng: np.random.Generator) -> Scan:
    """360 beams; a wall ``ahead_m`` in front and ``behind_m`` behind (inf: none), side walls
    1 m away; 1 % range noise."""
    angles = np.linspace(-math.pi, math.pi, BEAMS, endpoint=False)
    with np.errstate(divide="ignore"):
        side = 1.0 / np.abs(np.sin(angles))
        along = np.abs(np.cos(angles))
        front = np.where(np.cos(angles) > 0, ahead_m / along, behind_m / along)
    ranges = np.minimum(side, front)
    ranges = ranges + rng.standard_normal(BEAMS) * NOISE_FRACTION * ranges
    ranges[ranges > 12.0] = np.inf
    return Scan(ranges.astype(np.float32), angles, 0.15, 12.0)


def test_the_range_straight_ahead_is_the_median_of_the_beams_near_it() -> None:
    rng = np.random.default_rng(0)
    scan = _scan(5.0, 3.0, rng)
    assert abs(straight_range(scan, 0.0) - 5.0) < 0.1
    assert abs(straight_range(scan, math.pi) - 3.0) < 0.1
    far = _scan(MAX_RANGE_M + 1.0, 3.0, rng)  # near the lidar's reach: left out
    assert math.isnan(straight_range(far, 0.0))


def test_a_wall_ahead_measures_the_odometry_scale() -> None:
    rng = np.random.default_rng(1)
    true = np.arange(60) * STEP_M  # 6 m towards a wall 8.5 m ahead
    ranges = 8.5 - true
    ranges = ranges + rng.standard_normal(len(true)) * NOISE_FRACTION * ranges
    fit = fit_wall(true * ODOM_LONG, ranges, -1.0)
    assert fit is not None
    assert abs(fit.scale - 1 / ODOM_LONG) < 0.004
    assert abs(fit.span_m - 5.9 * ODOM_LONG) < 0.01


def test_a_person_in_the_beam_does_not_bend_the_fit() -> None:
    rng = np.random.default_rng(2)
    true = np.arange(60) * STEP_M
    ranges = 8.5 - true + rng.standard_normal(len(true)) * 0.02
    ranges[20:26] = 1.2  # someone crossing in front
    fit = fit_wall(true * ODOM_LONG, ranges, -1.0)
    assert fit is not None
    assert abs(fit.scale - 1 / ODOM_LONG) < 0.004


def test_too_short_a_stretch_or_another_wall_each_scan_gives_no_reading() -> None:
    rng = np.random.default_rng(3)
    short = np.arange(25) * STEP_M  # 2.4 m
    assert fit_wall(short * ODOM_LONG, 8.0 - short, -1.0) is None
    true = np.arange(60) * STEP_M
    jumping = rng.uniform(2.0, 8.0, len(true))  # no wall followed
    assert fit_wall(true, jumping, -1.0) is None


def test_a_straight_stretch_ends_at_a_turn_with_both_walls_read() -> None:
    """Driving 6 m down a corridor between walls 8.5 m ahead and 1 m behind the start, then
    turning: the stretch's fits come at the turn, one ahead and one behind."""
    rng = np.random.default_rng(4)
    ruler = EndWallRuler()
    odom = (0.0, 0.0, 0.3)  # the corridor runs at 0.3 rad in the odometry's frame
    fits = []
    for k in range(61):
        fits += ruler.step(odom, _scan(8.5 - k * STEP_M, 1.0 + k * STEP_M, rng))
        odom = compose(odom, (STEP_M * ODOM_LONG, 0.0, 0.0))
    assert fits == []
    fits = ruler.step(compose(odom, (0.0, 0.0, 0.2)), _scan(3.0, 3.0, rng))  # a turn
    assert len(fits) == 2
    for fit in fits:  # 61 ranges with 1 % noise: a fit is good to about 0.3 % (1 sigma)
        assert abs(fit.scale - 1 / ODOM_LONG) < 0.01
        assert fit.span_m > 3.0
    assert ruler.end() == []  # the new stretch has one scan


def test_a_robot_standing_still_keeps_no_endless_stretch() -> None:
    rng = np.random.default_rng(5)
    ruler = EndWallRuler()
    scan = _scan(5.0, 3.0, rng)
    for _ in range(MAX_SCANS + 10):
        assert ruler.step((1.0, 2.0, 0.5), scan) == []  # no travel: nothing to fit, no error
    assert len(ruler._travel) == 10  # the stretch started again after MAX_SCANS
    assert ruler.step((1.0, 2.0, 0.8), scan) == []  # a turn ends a stretch without travel


def test_the_calibration_takes_a_ruler_once_stretches_set_the_scale_and_not_far_from_it() -> None:
    cal = OdometryCalibration()
    assert not cal.add_ruler(1 / ODOM_LONG, 5.0)  # nothing compared yet: a walker could be ahead
    pose = odom = (0.0, 0.0, 0.0)
    everywhere = np.diag([1e4, 1e4, 1e5])
    for _ in range(round(GATE_AFTER_M / STEP_M) + 30):  # the stretches' 20 m, 1 % long
        pose, odom = compose(pose, (STEP_M, 0.0, 0.0)), compose(odom, (STEP_M * 1.01, 0.0, 0.0))
        cal.observe(pose, odom, everywhere)
    yaw = cal.yaw_per_m
    for _ in range(40):  # the ruler reads the true 2 %: it moves the scale
        assert cal.add_ruler(1 / ODOM_LONG, 5.0)
    assert abs(cal.scale - 1 / ODOM_LONG) < abs(cal.scale - 1 / 1.01)
    assert cal.yaw_per_m == yaw  # a ruler says nothing about the heading
    before = cal.scale
    assert not cal.add_ruler(0.9, 5.0)  # someone walking ahead at a tenth of the speed
    assert cal.ruler_outliers == 1
    assert cal.scale == before
    assert not cal.add_ruler(float("nan"), 5.0)
    assert not cal.add_ruler(1.0, 0.0)
