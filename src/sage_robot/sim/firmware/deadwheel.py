"""Dead-wheel encoders and the firmware's odometry (seed section 6, "Kinematics").

Geometry (REP 103, base_link at the robot's centre): the straight wheel sits at
(0, +DW_S_OFFSET_Y) and rolls along x; the horizontal wheel sits at (+DW_H_OFFSET_X, 0)
and rolls along y. For a body moving at (v, w):

    straight wheel ground speed    v_s = v - w * y_s
    horizontal wheel ground speed  v_h = w * x_h

so the firmware takes the heading rate from the horizontal wheel, ``w = v_h / x_h``,
and the forward speed from the straight wheel corrected by that rate,
``v = v_s + w * y_s``. Theta is kept in [0, 2 pi).
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from sage_robot.sim.firmware.params import EncoderFaults, FirmwareParams

TWO_PI = 2.0 * math.pi


class DeadWheels:
    """The two encoders: true body motion in, integer counts out (with faults)."""

    def __init__(self, params: FirmwareParams, faults: EncoderFaults, rng: np.random.Generator):
        self.p, self.faults, self.rng = params, faults, rng
        self._travel = np.zeros(2)  # true rolled distance of (straight, horizontal), m
        self.counts = np.zeros(2, dtype=np.int64)

    def roll(self, dt: float, v: float, w: float) -> tuple[int, int]:
        """Advance by the body's true motion; return the count changes (straight, horizontal)."""
        p, f = self.p, self.faults
        # Ground velocity at each wheel, projected on its (possibly tilted) rolling axis.
        d_s = (v - w * p.straight_offset_y_m) * math.cos(f.straight_tilt_rad) * dt
        d_h = (
            w * p.horizontal_offset_x_m * math.cos(f.horizontal_tilt_rad)
            + v * math.sin(f.horizontal_tilt_rad)
        ) * dt
        d = np.array([d_s, d_h])
        slip = np.array([f.straight_slip, f.horizontal_slip])
        if slip.any():
            d *= 1.0 - slip * self.rng.uniform(0.0, 2.0, 2)
        if f.noise_m > 0:
            d += self.rng.normal(0.0, f.noise_m, 2)
        self._travel += d
        new = np.floor(self._travel / p.metres_per_count).astype(np.int64)
        delta = new - self.counts
        self.counts = new
        return int(delta[0]), int(delta[1])


class DeadWheelOdometry:
    """The firmware's integration of count changes into (x, y, theta) and (v, w)."""

    def __init__(self, params: FirmwareParams) -> None:
        self.p = params
        self.x = self.y = self.theta = 0.0
        window = max(1, params.velocity_window_ticks)
        self._fwd: deque[float] = deque(maxlen=window)
        self._turn: deque[float] = deque(maxlen=window)
        self._dts: deque[float] = deque(maxlen=window)
        self.v = self.w = 0.0  # windowed means (m/s, rad/s), as sent in ODOM
        self.v_tick = self.w_tick = 0.0  # this tick's rates, for the PI loop

    def update(self, ds_counts: int, dh_counts: int, dt: float) -> None:
        m = self.p.metres_per_count
        dh = dh_counts * m
        dtheta = dh / self.p.horizontal_offset_x_m
        dfwd = ds_counts * m + dtheta * self.p.straight_offset_y_m
        mid = self.theta + 0.5 * dtheta
        self.x += dfwd * math.cos(mid)
        self.y += dfwd * math.sin(mid)
        self.theta = (self.theta + dtheta) % TWO_PI
        if self.theta >= TWO_PI:  # -1e-17 % 2 pi rounds to 2 pi
            self.theta = 0.0
        if dt > 0:
            self.v_tick, self.w_tick = dfwd / dt, dtheta / dt
            self._fwd.append(dfwd)
            self._turn.append(dtheta)
            self._dts.append(dt)
            total = sum(self._dts)
            self.v, self.w = sum(self._fwd) / total, sum(self._turn) / total

    @property
    def pose(self) -> tuple[float, float, float]:
        return (self.x, self.y, self.theta)
