"""The gyro's heading for SLAM: wheel odometry whose turns are measured by the IMU.

Scan matching with a lidar of 1 % range noise jitters the heading by a few tenths of a
degree from scan to scan, and every keyframe adds a little of it to the map's heading walk
(``docs/slam.md``, "The gyro's heading"). The robot's gyro (BNO08x, 100 Hz, bias calibrated
by the serial bridge at start-up) turns with a small scale error and a small residual bias,
but without that jitter. So SLAM takes its odometry steps as the wheels' travel turned by the
gyro's heading, and trusts the heading of such a step
(:attr:`~sage_robot.nav.slam.engine.SlamConfig.gyro_sigma_theta_rad`).

- :class:`GyroHeading` integrates the yaw rate (rad/s, about z) into a heading (rad,
  unwrapped) and interpolates it at a scan's stamp; a gap between samples longer than
  ``max_gap_s`` breaks it: no heading across the gap.
- :class:`GyroOdometry` keeps the fused odometry pose: each step takes the wheels' motion in
  the robot frame with its turn replaced by the gyro's, and falls back to the wheels' turn
  where the gyro has no heading.

Pure: no I/O, no clock; stamps are the messages' (s).
"""

from __future__ import annotations

import bisect
from collections import deque

from sage_robot.core.geometry import compose, relative

Pose = tuple[float, float, float]

GYRO_MAX_GAP_S = 0.1  # the IMU runs at 100 Hz: a longer silence breaks the heading
GYRO_HISTORY_S = 2.0  # headings kept to interpolate at scan stamps (scans lag the IMU)


class GyroHeading:
    """The integrated yaw rate, by stamp."""

    def __init__(self, max_gap_s: float = GYRO_MAX_GAP_S, history_s: float = GYRO_HISTORY_S) -> None:
        self.max_gap_s = max_gap_s
        self.history_s = history_s
        self._stamps: deque[float] = deque()
        self._headings: deque[float] = deque()
        self._rate = 0.0
        self.segment = 0  # bumps at every break: headings of different segments do not compare
        self._segments: deque[int] = deque()

    def add(self, stamp: float, yaw_rate: float) -> None:
        """One gyro sample (s, rad/s); stamps must increase (an older one is ignored)."""
        if self._stamps and stamp <= self._stamps[-1]:
            return
        if not self._stamps or stamp - self._stamps[-1] > self.max_gap_s:
            heading = 0.0 if not self._headings else self._headings[-1]
            if self._stamps:
                self.segment += 1
        else:  # trapezoid: the rate changed linearly between the two samples
            heading = self._headings[-1] + 0.5 * (self._rate + yaw_rate) * (stamp - self._stamps[-1])
        self._stamps.append(stamp)
        self._headings.append(heading)
        self._segments.append(self.segment)
        self._rate = yaw_rate
        while self._stamps and self._stamps[0] < stamp - self.history_s:
            self._stamps.popleft()
            self._headings.popleft()
            self._segments.popleft()

    def at(self, stamp: float) -> tuple[int, float] | None:
        """(segment, heading rad) at ``stamp``, interpolated between the samples around it, or
        at most ``max_gap_s`` past the last one at its rate (a scan may come before the IMU's
        next sample); None before the samples kept, further ahead, or across a break."""
        stamps = self._stamps
        k = bisect.bisect_left(stamps, stamp)
        if k < len(stamps) and stamps[k] == stamp:
            return self._segments[k], self._headings[k]
        if k == len(stamps) and stamps and stamp - stamps[-1] <= self.max_gap_s:
            return self.segment, self._headings[-1] + self._rate * (stamp - stamps[-1])
        if k == 0 or k == len(stamps) or self._segments[k - 1] != self._segments[k]:
            return None
        t0, t1 = stamps[k - 1], stamps[k]
        f = (stamp - t0) / (t1 - t0)
        h0, h1 = self._headings[k - 1], self._headings[k]
        return self._segments[k], h0 + f * (h1 - h0)


class GyroOdometry:
    """Wheel odometry poses in, the same travel with the gyro's turns out."""

    def __init__(self) -> None:
        self.pose: Pose | None = None  # the fused odometry pose
        self._wheels: Pose | None = None
        self._heading: tuple[int, float] | None = None

    def step(self, wheels: Pose, heading: tuple[int, float] | None) -> tuple[Pose, bool]:
        """The fused pose for the wheel odometry pose ``wheels`` and the gyro's
        :meth:`GyroHeading.at` at the same stamp, and whether the gyro turned this step."""
        gyro = False
        if self.pose is None or self._wheels is None:
            self.pose = wheels
        else:
            dx, dy, dth = relative(self._wheels, wheels)
            if heading is not None and self._heading is not None and heading[0] == self._heading[0]:
                dth, gyro = heading[1] - self._heading[1], True
            self.pose = compose(self.pose, (dx, dy, dth))
        self._wheels, self._heading = wheels, heading
        return self.pose, gyro
