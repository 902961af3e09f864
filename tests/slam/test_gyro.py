"""The gyro's heading for SLAM: integrating the yaw rate, and wheel odometry turned by it."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from sage_robot.core.geometry import compose, relative
from sage_robot.nav.slam import engine
from sage_robot.nav.slam.engine import Slam, SlamConfig
from sage_robot.nav.slam.gyro import GyroHeading, GyroOdometry
from sage_robot.nav.slam.points import Scan
from sage_robot.nav.slam.posegraph import KIND_ODOM
from sage_robot.nav.slam.trajectory import align

from .synth import corridor_loop, loop_path, simulate

RATE_HZ = 100.0


def _feed(gyro: GyroHeading, t0: float, t1: float, rate: float) -> None:
    n = round((t1 - t0) * RATE_HZ)
    for i in range(n + 1):
        gyro.add(t0 + i / RATE_HZ, rate)


def _heading(gyro: GyroHeading, stamp: float) -> float:
    """The heading at ``stamp``, which must be in the first segment."""
    at = gyro.at(stamp)
    assert at is not None
    assert at[0] == 0
    return at[1]


def test_a_constant_rate_integrates_to_its_heading_and_interpolates_between_samples() -> None:
    gyro = GyroHeading()
    _feed(gyro, 10.0, 11.0, 0.5)
    start = _heading(gyro, 10.0)
    assert _heading(gyro, 11.0) == pytest.approx(start + 0.5)
    assert _heading(gyro, 10.505) == pytest.approx(start + 0.2525)
    # a scan may come before the next sample: at most max_gap_s ahead, at the last rate
    assert _heading(gyro, 11.05) == pytest.approx(start + 0.525)
    assert gyro.at(11.2) is None
    assert gyro.at(8.0) is None  # before the first sample


def test_a_changing_rate_is_integrated_by_trapezoids() -> None:
    gyro = GyroHeading()
    for i in range(101):  # the rate ramps 0 -> 1 rad/s over 1 s: the heading is t^2 / 2
        gyro.add(i / RATE_HZ, i / RATE_HZ)
    assert _heading(gyro, 1.0) == pytest.approx(0.5)


def test_a_silence_breaks_the_heading_and_old_samples_are_dropped() -> None:
    gyro = GyroHeading(max_gap_s=0.1, history_s=2.0)
    _feed(gyro, 0.0, 1.0, 1.0)
    _feed(gyro, 1.5, 2.5, 1.0)  # 0.5 s without a sample
    before, after = gyro.at(0.9), gyro.at(2.0)
    assert before is not None
    assert after is not None
    assert before[0] != after[0]  # different segments: not to be compared
    assert gyro.at(1.3) is None  # inside the gap
    gyro.add(2.4, 5.0)  # older than the last sample: ignored
    assert gyro.at(2.5)[1] == pytest.approx(after[1] + 0.5)  # type: ignore[index]
    _feed(gyro, 2.51, 5.0, 1.0)
    assert gyro.at(2.0) is None  # more than history_s ago


def test_the_fused_odometry_takes_the_wheels_travel_and_the_gyros_turn() -> None:
    fuse = GyroOdometry()
    assert fuse.step((1.0, 2.0, 0.0), (0, 0.0)) == ((1.0, 2.0, 0.0), False)
    # the wheels say 1 m ahead and a 0.3 rad turn; the gyro says 0.2 rad
    pose, gyro = fuse.step((2.0, 2.0, 0.3), (0, 0.2))
    assert gyro
    assert pose == pytest.approx((2.0, 2.0, 0.2))
    # the next metre goes along the fused heading, not the wheels'
    wheels = (2.0 + math.cos(0.3), 2.0 + math.sin(0.3), 0.3)
    pose, gyro = fuse.step(wheels, (0, 0.2))
    assert gyro
    assert pose == pytest.approx((2.0 + math.cos(0.2), 2.0 + math.sin(0.2), 0.2))
    # no gyro heading (or a new segment): the wheels' turn
    pose, gyro = fuse.step((wheels[0], wheels[1], 0.4), None)
    assert not gyro
    assert pose[2] == pytest.approx(0.3)
    pose, gyro = fuse.step((wheels[0], wheels[1], 0.5), (1, 7.0))
    assert not gyro  # the previous step had none
    assert pose[2] == pytest.approx(0.4)
    pose, gyro = fuse.step((wheels[0], wheels[1], 0.5), (1, 7.1))
    assert gyro
    assert pose[2] == pytest.approx(0.5)


@pytest.mark.parametrize("gyro", [False, True])
def test_the_trackers_glitch_guesses_keep_the_gyros_turn(gyro: bool) -> None:
    """A doubtful match makes the tracker also try "as the last step" and "no motion" (the
    wheels freeze, then jump); a turn the gyro measured stays in both guesses."""
    truth = loop_path(step_m=0.3)[:3]
    drive = simulate(corridor_loop(), truth)
    slam = Slam()
    for k in range(2):
        slam.add_scan(0.2 * k, drive.odom[k], drive.scans[k], gyro=gyro)
    guesses: list[tuple[float, float, float]] = []

    def fake_track(q: object, predicted: tuple[float, float, float], view: object) -> None:
        guesses.append(predicted)  # and no match: the match is doubtful

    slam._track = fake_track  # type: ignore[method-assign]
    pose = slam.pose
    odom = (drive.odom[1][0], drive.odom[1][1], drive.odom[1][2] + 0.1)  # turned 0.1 rad on the spot
    slam.add_scan(0.4, odom, drive.scans[1], gyro=gyro)
    assert len(guesses) == 3  # the odometry's prediction, then the two glitch guesses
    turns = [math.remainder(g[2] - pose[2], 2 * math.pi) for g in guesses]
    assert turns[0] == pytest.approx(0.1)
    if gyro:
        assert turns[1:] == [pytest.approx(0.1), pytest.approx(0.1)]
    else:
        assert turns[2] == pytest.approx(0.0)  # "no motion": the wheels' turn is doubted too


@pytest.mark.parametrize("gyro", [False, True])
def test_keyframes_the_gyro_turned_get_the_gyros_odometry_edges(gyro: bool) -> None:
    """An odometry edge between keyframes whose every step the gyro turned has the gyro's
    heading noise and ``gyro_odom_sigma_xy_*`` for x and y; the wheels' edges keep theirs."""
    truth = loop_path(step_m=0.1)[:12]
    drive = simulate(corridor_loop(), truth)
    cfg = dataclasses.replace(SlamConfig(), gyro_odom_sigma_xy_m=0.005, gyro_odom_sigma_xy_fraction=0.03)
    slam = Slam(cfg, initial_pose=truth[0])
    for k in range(len(truth)):
        slam.add_scan(0.2 * k, drive.odom[k], drive.scans[k], gyro=gyro)
    edges = [e for e in slam.graph.edges if e.kind == KIND_ODOM]
    assert len(edges) >= 2
    for e in edges[1:]:  # the first keyframe's own scan had no step before it
        dist, turn = math.hypot(e.z[0], e.z[1]), abs(e.z[2])
        sxy, sth = e.information[0, 0] ** -0.5, e.information[2, 2] ** -0.5
        if gyro:
            assert sxy == pytest.approx(0.005 + 0.03 * dist)
            assert sth == pytest.approx(cfg.gyro_sigma_theta_rad + cfg.gyro_sigma_turn_fraction * turn)
        else:
            assert sxy == pytest.approx(cfg.odom_sigma_xy_m + cfg.odom_sigma_fraction * dist)
            assert sth == pytest.approx(cfg.odom_sigma_theta_rad + cfg.odom_sigma_fraction * turn)


Pose = tuple[float, float, float]
SLIP_STEP = 200  # the scan whose odometry step slipped (20 m into the lap)


def _slipping_drive(slip_m: float) -> tuple[list[Pose], list[Pose], list[Scan]]:
    """A lap of the drawn corridor with the gyro's heading; the wheels read ``slip_m`` too far
    on one step (they spun on a threshold)."""
    truth = loop_path(step_m=0.1)
    drive = simulate(corridor_loop(), truth, yaw_drift=0.0)
    rng = np.random.default_rng(0)
    odom = [truth[0]]
    for k in range(1, len(truth)):
        dx, dy, dth = relative(truth[k - 1], truth[k])
        slip = slip_m if k == SLIP_STEP else 0.0
        odom.append(compose(odom[-1], (dx + rng.normal(0, 0.002) + slip, dy + rng.normal(0, 0.002), dth)))
    return truth, odom, drive.scans


@pytest.mark.parametrize("gate", [True, False])
def test_a_wheel_slip_does_not_bend_the_map_through_a_stiff_odometry_edge(
    gate: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Odometry edges the gyro turned are stiff (5 mm + 3 %); when the wheels slip 0.3 m, the
    scan match disagrees by far more than the edge's noise and the edge falls back to the
    wheels' weak noise, so the loop's map keeps its shape (without that gate, it bends)."""
    if not gate:
        monkeypatch.setattr(engine, "SLIP_SIGMAS", math.inf)
    truth, odom, scans = _slipping_drive(0.3)
    cfg = dataclasses.replace(SlamConfig(), gyro_odom_sigma_xy_m=0.005, gyro_odom_sigma_xy_fraction=0.03)
    slam = Slam(cfg, initial_pose=truth[0])
    for k in range(len(truth)):
        slam.add_scan(0.2 * k, odom[k], scans[k], gyro=True)
    assert slam.loop_closures > 5
    _, est = slam.trajectory_array()
    error = align(est[:, :2], np.asarray(truth)[:, :2]).rmse_m
    if gate:
        assert slam.odometry_slips == 1
        assert error < 0.01  # as without a slip (0.0065 m)
    else:
        assert error > 0.015  # 0.022 m: the slip's edge pulled the keyframes after it along
