"""FlatFloor: the body of a robot alone on an endless flat floor (no walls, no slip).

It turns drive-wheel ground speeds into the body's true motion, the job the simulated
world does when there is one. Any object with the same ``step`` (a :class:`SimBody`)
can take its place.
"""

from __future__ import annotations

import math
from typing import Protocol

from sage_robot.core.geometry import wrap_angle

TRACK_WIDTH_M = 0.381  # Lw of the seed's robot


class SimBody(Protocol):
    def step(self, dt: float, wheel_speeds: tuple[float, float]) -> tuple[float, float]:
        """Move for ``dt`` s with (left, right) wheel ground speeds in m/s; return the true
        body (v m/s, w rad/s) after collisions."""
        ...


class FlatFloor:
    """Differential-drive kinematics, integrated exactly over each step (arc motion).

    ``pose`` is (x m, y m, theta rad in [-pi, pi)) in the floor's frame, REP 103.
    """

    def __init__(
        self,
        track_width_m: float = TRACK_WIDTH_M,
        pose: tuple[float, float, float] = (0.0, 0.0, 0.0),
    ) -> None:
        self.track_width_m = track_width_m
        self.pose = pose
        self.distance_m = 0.0  # total path length travelled

    def step(self, dt: float, wheel_speeds: tuple[float, float]) -> tuple[float, float]:
        left, right = wheel_speeds
        v = 0.5 * (left + right)
        w = (right - left) / self.track_width_m
        x, y, th = self.pose
        if abs(w) < 1e-9:
            x += v * dt * math.cos(th)
            y += v * dt * math.sin(th)
        else:
            r = v / w
            x += r * (math.sin(th + w * dt) - math.sin(th))
            y -= r * (math.cos(th + w * dt) - math.cos(th))
        self.pose = (x, y, wrap_angle(th + w * dt))
        self.distance_m += abs(v) * dt
        return v, w
