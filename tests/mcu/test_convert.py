"""Frame -> message conversions and the IMU calibrator (pure)."""

from __future__ import annotations

import math

import pytest

from sage_robot.hardware.mcu.convert import (
    ImuCalibrator,
    battery_percentage,
    clamp_command,
    odometry_from,
)

CURVE = ((12.0, 0.0), (14.0, 0.3), (16.8, 1.0))


def test_odometry_wraps_the_firmwares_theta_to_minus_pi_pi():
    odom = odometry_from((1.0, 2.0, 6.0, 0.3, -0.1), stamp=4.0)
    assert odom.pose.theta == pytest.approx(6.0 - 2 * math.pi)
    assert odom.pose.x == 1.0
    assert odom.twist.linear_x == pytest.approx(0.3)
    assert odom.stamp == 4.0
    assert (odom.frame_id, odom.child_frame_id) == ("odom", "base_link")
    assert odometry_from((0, 0, math.pi, 0, 0), 0).pose.theta == pytest.approx(-math.pi)


def test_battery_percentage_interpolates_and_clips():
    assert battery_percentage(13.0, CURVE) == pytest.approx(0.15)
    assert battery_percentage(10.0, CURVE) == 0.0
    assert battery_percentage(18.0, CURVE) == 1.0


def test_clamp_command():
    assert clamp_command(-0.5, 0.2, 0.8, 1.0, allow_reverse=False) == (0.0, 0.2)
    assert clamp_command(-0.5, 0.2, 0.8, 1.0, allow_reverse=True) == (-0.5, 0.2)
    assert clamp_command(2.0, -3.0, 0.8, 1.0, allow_reverse=False) == (0.8, -1.0)
    assert clamp_command(math.nan, math.inf, 0.8, 1.0, allow_reverse=False) == (0.0, 0.0)


def test_imu_calibrator_restarts_when_the_robot_moves():
    cal = ImuCalibrator(window_s=1.0)
    still = ((0.01, -0.02, 0.005), (0.0, 0.0, 9.81))
    for k in range(50):
        assert not cal.add(k * 0.01, *still).done
    moved = cal.add(0.5, (0.01, -0.02, 0.4), (0.0, 0.0, 9.81))
    assert moved.moved
    assert cal.retries == 1
    t = 0.51
    while not cal.add(t, *still).done:
        t += 0.01
        assert t < 3.0
    assert t == pytest.approx(1.51, abs=0.02)  # a full new window after the motion
    assert cal.bias == pytest.approx((0.01, -0.02, 0.005))
    assert cal.retries == 1
    imu = cal.correct((0.01, -0.02, 0.505, 0.1, 0.0, 9.8), stamp=2.0)
    assert imu.angular_velocity == pytest.approx((0.0, 0.0, 0.5))


def test_voltage_smoother_rides_out_load_sag_but_follows_a_real_change():
    from sage_robot.hardware.mcu.convert import BATTERY_SMOOTHING_TAU_S, VoltageSmoother

    s = VoltageSmoother()
    assert s.update(15.8, 0.0) == 15.8  # the first reading is taken as is
    for k in range(1, 501):  # 10 s of driving at 50 Hz: the pack sags to 15.3 V
        s.update(15.3, k * 0.02)
    expected = 15.3 + 0.5 * math.exp(-10.0 / BATTERY_SMOOTHING_TAU_S)
    assert s.value == pytest.approx(expected, abs=1e-3)  # an EMA on the clock's dt
    for k in range(501, 501 + 50 * 300):  # five minutes later it has followed
        s.update(15.3, k * 0.02)
    assert s.value == pytest.approx(15.3, abs=0.01)
    batch = VoltageSmoother(10.0)  # samples stamped alike (a late RX thread) add no weight
    batch.update(16.0, 0.0)
    assert batch.update(12.0, 0.0) == 16.0
    assert batch.update(12.0, 10.0) == pytest.approx(
        12.0 + 4.0 * math.exp(-1.0)
    )
    with pytest.raises(ValueError, match="time constant"):
        VoltageSmoother(-1.0)
