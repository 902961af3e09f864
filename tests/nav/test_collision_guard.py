"""The collision guard: the live scan's last word on a velocity, in the robot's own frame."""

from __future__ import annotations

import math

import numpy as np

from sage_robot.nav.collision_guard import MARGIN_M, guarded, leg_like, scan_points

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


def _arc(cx: float, cy: float, r: float, n: int) -> np.ndarray:
    """Returns on the half of a circle that faces the lidar at the origin, in beam order."""
    face = math.atan2(-cy, -cx)
    a = np.linspace(face - math.pi / 2 + 0.2, face + math.pi / 2 - 0.2, n)
    pts = np.column_stack([cx + r * np.cos(a), cy + r * np.sin(a)])
    return pts[np.argsort(np.arctan2(pts[:, 1], pts[:, 0]))]


def _wall(x: float, y0: float, y1: float, n: int) -> np.ndarray:
    return np.column_stack([np.full(n, x), np.linspace(y0, y1, n)])


def test_a_persons_legs_keep_the_body_clear_of_the_body_around_them() -> None:
    # A person 0.515 m ahead (the bodies touch at 0.5), legs 0.11 m either side of the body's
    # centre, a wall 3 m behind.
    # Head-on, the body's front (0.25 m) lies 0.23 m beyond the legs' returns: 2 cm from the
    # legs the robot already touched the body (the TurtleBot sandbox: a stander, pressed on).
    legs = np.vstack([_arc(0.515, -0.11, 0.035, 6), _arc(0.515, 0.11, 0.035, 6)])
    scene = np.vstack([_wall(3.6, -1.5, -0.3, 30), legs, _wall(3.6, 0.3, 1.5, 30)])
    scene = scene[np.argsort(np.arctan2(scene[:, 1], scene[:, 0]))]
    marks = leg_like(scene)
    assert marks[np.isin(scene, legs).all(axis=1)].all()  # both legs
    assert not marks[scene[:, 0] > 3.0].any()  # not the wall
    # 1.5 cm on, the bodies would touch: with the legs' margin it stops, while 2 cm from the
    # legs alone would let it on
    assert guarded(0.15, 0.0, scene, RADIUS_M) == 0.15
    assert guarded(0.15, 0.0, scene, RADIUS_M, legs=marks) == 0.0
    assert guarded(0.0, 0.8, scene, RADIUS_M, legs=marks) == 0.0  # it may still turn away
    assert guarded(-0.1, 0.0, scene, RADIUS_M, legs=marks) == -0.1


def test_a_door_frame_or_a_pillar_is_not_a_leg() -> None:
    # A doorway's frame: its returns run on into the wall beside it (no gap behind them).
    frame = np.vstack([_wall(0.6, -1.0, -0.45, 12), _wall(1.5, -0.4, 0.4, 16), _wall(0.6, 0.45, 1.0, 12)])
    frame = frame[np.argsort(np.arctan2(frame[:, 1], frame[:, 0]))]
    assert not leg_like(frame[frame[:, 0] < 1.0]).any()  # the frame's two sides alone
    pillar = _arc(0.8, 0.0, 0.2, 20)  # 0.4 m across, standing clear: too wide for a leg
    assert not leg_like(np.vstack([_wall(3.0, -1.5, -0.6, 10), pillar, _wall(3.0, 0.6, 1.5, 10)])).any()
    # a pillar's face 5 mm beyond the ordinary margin still stops it, legs or no legs
    pts = _pillar(0.25 + MARGIN_M + 0.1 + 0.005, 0.0)
    assert guarded(0.15, 0.0, pts, RADIUS_M, legs=leg_like(pts)) == 0.0
