"""The seed-2025 firmware's motor encoders and the odometry it integrates from them.

The encoders sit on the motors, so they count *wheel rotation*, not the robot's motion
over the ground: a wheel spinning against a wall still counts (the classic wheel-odometry
error; the documented firmware's dead wheels do not have it). Counts are whole numbers,
``floor(travel / metres_per_count)`` per wheel.

At each 100 Hz tick the firmware takes the count changes (dl, dr in counts), turns them
into wheel travel and speed (the PI's feedback: one count per 10 ms is 0.127 m/s), and
integrates differential drive with its own track constant:

    ds = (dl + dr) / 2,  dtheta = (dr - dl) / track,  x += ds cos(theta + dtheta / 2), ...
    theta = fmodf(theta + dtheta, 2 pi)

The state is float32, as on the MCU; ``fmodf`` keeps theta in (-2 pi, 2 pi), negative
after a net clockwise turn. (x, y) REP 103: x forward at boot, y left.
"""

from __future__ import annotations

import math
import struct

from sage_robot.sim.firmware.seed2025_params import Seed2025Params

_F32 = struct.Struct("<f")


def f32(x: float) -> float:
    """``x`` rounded to the nearest float32, as the MCU stores it."""
    return float(_F32.unpack(_F32.pack(x))[0])


TWO_PI_F32 = f32(2.0 * math.pi)  # 6.2831855 > 2 pi; the float32 below it is < 2 pi


class MotorEncoders:
    """Two quadrature encoders on the motor shafts: wheel rotation in, whole counts out."""

    def __init__(self, metres_per_count: float) -> None:
        self.metres_per_count = metres_per_count
        self._travel = [0.0, 0.0]  # rolled distance of (left, right) wheel, m
        self.counts = (0, 0)

    def roll(self, dt: float, left_mps: float, right_mps: float) -> None:
        self._travel[0] += left_mps * dt
        self._travel[1] += right_mps * dt
        m = self.metres_per_count
        self.counts = (math.floor(self._travel[0] / m), math.floor(self._travel[1] / m))


class EncoderOdometry:
    """The firmware's per-tick wheel speeds and its (x, y, theta), from count changes."""

    def __init__(self, params: Seed2025Params, counts: tuple[int, int] = (0, 0)) -> None:
        self.p = params
        self._m_per_count = f32(params.metres_per_count)
        self._track = f32(params.track_width_m)
        self.reset(counts)

    def reset(self, counts: tuple[int, int]) -> None:
        """Boot: pose at zero, counting from ``counts``."""
        self.x = self.y = self.theta = 0.0
        self.wheel_speeds = (0.0, 0.0)  # (left, right) m/s, measured this tick
        self.v = self.w = 0.0  # body speeds from them (m/s, rad/s), as sent in ODOM
        self._last = counts

    def update(self, counts: tuple[int, int], dt: float) -> None:
        dl = (counts[0] - self._last[0]) * self._m_per_count
        dr = (counts[1] - self._last[1]) * self._m_per_count
        self._last = counts
        ds = 0.5 * (dl + dr)
        dtheta = (dr - dl) / self._track
        mid = self.theta + 0.5 * dtheta
        self.x = f32(self.x + ds * math.cos(mid))
        self.y = f32(self.y + ds * math.sin(mid))
        self.theta = math.fmod(f32(self.theta + dtheta), TWO_PI_F32)
        self.wheel_speeds = (f32(dl / dt), f32(dr / dt))
        self.v, self.w = f32(ds / dt), f32(dtheta / dt)

    @property
    def pose(self) -> tuple[float, float, float]:
        return (self.x, self.y, self.theta)
