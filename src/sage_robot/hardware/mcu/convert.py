"""Pure conversions between MCU frames and bus messages (no I/O, no clock).

Conventions: REP 103 (x forward, y left, theta counter-clockwise); the firmware's
theta is in [0, 2 pi) (documented) or (-2 pi, 2 pi) (seed-2025), the bus's in [-pi, pi).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from sage_robot.core.geometry import wrap_angle
from sage_robot.core.msgs import BatteryState, Imu, Odometry, Pose2D, Twist

# Covariances of dead-wheel odometry, row-major 3x3 over (x, y, theta) and (vx, vy, wz).
# Diagonal only; the values are the usual order of magnitude for calibrated dead wheels.
POSE_VAR_XY_M2 = 1e-3
POSE_VAR_THETA_RAD2 = 1e-2
TWIST_VAR_V = 1e-3  # (m/s)^2
TWIST_VAR_W = 1e-2  # (rad/s)^2
POSE_COVARIANCE = (POSE_VAR_XY_M2, 0, 0, 0, POSE_VAR_XY_M2, 0, 0, 0, POSE_VAR_THETA_RAD2)
TWIST_COVARIANCE = (TWIST_VAR_V, 0, 0, 0, 1e-6, 0, 0, 0, TWIST_VAR_W)


def clamp_command(v: float, w: float, max_v: float, max_w: float, allow_reverse: bool) -> tuple[float, float]:
    """Clamp a velocity command to the profile's limits; v < 0 becomes 0 unless reverse
    is allowed. NaN/inf become 0 (a stop is the only safe reading of garbage)."""
    v = v if math.isfinite(v) else 0.0
    w = w if math.isfinite(w) else 0.0
    v = min(max(v, -max_v if allow_reverse else 0.0), max_v)
    w = min(max(w, -max_w), max_w)
    return float(v), float(w)


def odometry_from(values: Sequence[float], stamp: float) -> Odometry:
    """ODOM payload (x, y, theta in (-2 pi, 2 pi), v, w) -> Odometry in odom/base_link."""
    x, y, theta, v, w = values
    return Odometry(
        stamp=stamp,
        pose=Pose2D(float(x), float(y), wrap_angle(float(theta))),
        twist=Twist(float(v), float(w)),
        pose_covariance=tuple(float(c) for c in POSE_COVARIANCE),
        twist_covariance=tuple(float(c) for c in TWIST_COVARIANCE),
    )


def battery_percentage(voltage: float, curve: Sequence[tuple[float, float]]) -> float:
    """Charge 0..1 from the (voltage, charge) discharge curve, linear between points."""
    volts = [p[0] for p in curve]
    charge = [p[1] for p in curve]
    return float(np.clip(np.interp(voltage, volts, charge), 0.0, 1.0))


def battery_from(voltage: float, curve: Sequence[tuple[float, float]], stamp: float) -> BatteryState:
    return BatteryState(stamp, float(voltage), battery_percentage(voltage, curve))


BATTERY_SMOOTHING_TAU_S = 30.0  # time constant of the battery voltage's moving average (s)


class VoltageSmoother:
    """Exponential moving average of the pack voltage on irregular samples (``t`` in s of
    the node's clock): each sample weighs ``1 - exp(-dt / tau)``. The motors' current
    sags the terminal voltage by ~0.5 V while driving (15.8 V -> 15.3 V, 87 % -> 77 % on
    the curve) and it springs back at rest; a 30 s average keeps the percentage a
    battery watchdog reads (3 % hysteresis) from flapping with every start and stop,
    while a real discharge (hours) passes through. The first sample is taken as is."""

    def __init__(self, tau_s: float = BATTERY_SMOOTHING_TAU_S) -> None:
        if tau_s < 0:
            raise ValueError(f"smoothing time constant must be >= 0 s, got {tau_s}")
        self.tau_s = tau_s
        self.value: float | None = None
        self._t: float | None = None

    def update(self, voltage: float, t: float) -> float:
        if self.value is None or self._t is None or self.tau_s == 0:
            self.value, self._t = voltage, t
            return voltage
        dt = max(0.0, t - self._t)
        self._t = max(self._t, t)
        self.value += (1.0 - math.exp(-dt / self.tau_s)) * (voltage - self.value)
        return self.value


@dataclass
class CalibrationResult:
    done: bool
    moved: bool = False  # the window was spoiled by motion; a new one started


class ImuCalibrator:
    """The seed's start-up gyro bias calibration: the robot stands still for a window.

    Feed every IMU sample. A sample whose turn rate differs from the window's running
    mean by more than ``motion_radps`` (or whose acceleration differs by more than
    ``motion_mps2``) means the robot moved: the window restarts (``moved`` is reported
    so the caller can say so). After ``window_s`` of stillness the mean gyro is the bias.
    """

    def __init__(self, window_s: float, motion_radps: float = 0.05, motion_mps2: float = 0.5) -> None:
        self.window_s, self.motion_radps, self.motion_mps2 = window_s, motion_radps, motion_mps2
        self.bias: tuple[float, float, float] | None = None
        self.retries = 0
        self._reset(None)

    def _reset(self, t0: float | None) -> None:
        self._t0 = t0
        self._n = 0
        self._gyro_sum = np.zeros(3)
        self._accel_sum = np.zeros(3)

    def add(self, t: float, gyro: Sequence[float], accel: Sequence[float]) -> CalibrationResult:
        if self.bias is not None:
            return CalibrationResult(True)
        g, a = np.asarray(gyro, dtype=float), np.asarray(accel, dtype=float)
        if self._t0 is None:
            self._reset(t)
        if self._n:
            g_mean, a_mean = self._gyro_sum / self._n, self._accel_sum / self._n
            if (
                np.max(np.abs(g - g_mean)) > self.motion_radps
                or np.max(np.abs(a - a_mean)) > self.motion_mps2
            ):
                self.retries += 1
                self._reset(None)  # a fresh window starts with the next sample
                return CalibrationResult(False, moved=True)
        self._n += 1
        self._gyro_sum += g
        self._accel_sum += a
        assert self._t0 is not None
        if t - self._t0 >= self.window_s:
            mean = self._gyro_sum / self._n
            self.bias = (float(mean[0]), float(mean[1]), float(mean[2]))
            return CalibrationResult(True)
        return CalibrationResult(False)

    def correct(self, values: Sequence[float], stamp: float) -> Imu:
        """IMU payload (gx, gy, gz, ax, ay, az) -> Imu with the bias removed."""
        bx, by, bz = self.bias or (0.0, 0.0, 0.0)
        gx, gy, gz, ax, ay, az = (float(v) for v in values)
        return Imu(stamp, (gx - bx, gy - by, gz - bz), (ax, ay, az))
