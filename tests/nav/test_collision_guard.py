"""The collision guard: the live scan's last word on a velocity, in the robot's own frame."""

from __future__ import annotations

import math

import numpy as np

from sage_robot.nav.collision_guard import MARGIN_M, guarded, scan_points

RADIUS_M = 0.25


def _pillar(x: float, y: float, r: float = 0.1, n: int = 24) -> np.ndarray:
    a = np.linspace(0, 2 * math.pi, n, endpoint=False)
    return np.column_stack([x + r * np.cos(a), y + r * np.sin(a)])


def test_stops_short_of_a_pillar_ahead_and_lets_it_turn_or_back_away() -> None:
    pts = _pillar(0.25 + MARGIN_M + 0.1 + 0.005, 0.0)  # its face 5 mm beyond the margin
    assert guarded(0.15, 0.0, pts, RADIUS_M) == 0.0  # 1.5 cm more would cross the margin
    assert guarded(0.0, 0.8, pts, RADIUS_M) == 0.0  # turning in place: v stays 0, w is not touched
    assert guarded(-0.1, 0.0, pts, RADIUS_M) == -0.1  # away from it
    far = _pillar(1.0, 0.0)
    assert guarded(0.5, 0.0, far, RADIUS_M) == 0.5


def test_a_pillar_beside_the_way_does_not_stop_it() -> None:
    beside = _pillar(0.0, 0.25 + MARGIN_M + 0.1 + 0.001)  # its face 1 mm beyond the margin, left
    assert guarded(0.15, 0.0, beside, RADIUS_M) == 0.15
    assert guarded(0.15, -2.5, beside, RADIUS_M) == 0.15  # curving away from it
    # ... but curving toward it does
    assert guarded(0.3, 2.5, beside, RADIUS_M) == 0.0


def test_returns_inside_the_body_are_the_robot_itself() -> None:
    own = np.array([[0.05, 0.1], [-0.1, -0.05]])
    assert guarded(0.5, 0.0, own, RADIUS_M) == 0.5
    assert guarded(0.5, 0.0, np.zeros((0, 2)), RADIUS_M) == 0.5


def test_scan_points_in_the_robot_frame() -> None:
    angles = np.array([0.0, math.pi / 2, math.pi])
    ranges = np.array([1.0, np.inf, 12.0])  # no return, and a return at range_max (none either)
    pts = scan_points(angles, ranges, 12.0, (0.1, 0.0, math.pi))  # mounted backwards, 0.1 m ahead
    assert pts.shape == (1, 2)
    assert np.allclose(pts[0], [-0.9, 0.0])
