"""SE(2) helpers. Conventions: x forward, y left, theta counter-clockwise (rad), as ROS REP 103.

A pose (x, y, theta) maps points from its child frame to its parent frame.
"""

from __future__ import annotations

import math

import numpy as np

TWO_PI = 2.0 * math.pi


def wrap_angle(a: float) -> float:
    """Wrap an angle to [-pi, pi)."""
    return (a + math.pi) % TWO_PI - math.pi


def wrap_angle_positive(a: float) -> float:
    """Wrap an angle to [0, 2*pi) — the STM32 firmware's convention for theta."""
    return a % TWO_PI


def wrap_angles(a: np.ndarray) -> np.ndarray:
    """Vectorised :func:`wrap_angle`."""
    return (a + np.pi) % (2.0 * np.pi) - np.pi


def compose(
    a: tuple[float, float, float], b: tuple[float, float, float]
) -> tuple[float, float, float]:
    """a ⊕ b: pose b (expressed in a's frame) seen from a's parent frame."""
    ax, ay, at = a
    bx, by, bt = b
    c, s = math.cos(at), math.sin(at)
    return (ax + c * bx - s * by, ay + s * bx + c * by, wrap_angle(at + bt))


def inverse(a: tuple[float, float, float]) -> tuple[float, float, float]:
    """⊖a, so that compose(a, inverse(a)) == (0, 0, 0)."""
    ax, ay, at = a
    c, s = math.cos(at), math.sin(at)
    return (-c * ax - s * ay, s * ax - c * ay, wrap_angle(-at))


def relative(
    a: tuple[float, float, float], b: tuple[float, float, float]
) -> tuple[float, float, float]:
    """⊖a ⊕ b: pose b expressed in the frame of pose a."""
    return compose(inverse(a), b)


def transform_points(pose: tuple[float, float, float], pts: np.ndarray) -> np.ndarray:
    """Map an (N, 2) array of points from the pose's frame to its parent frame."""
    x, y, t = pose
    c, s = math.cos(t), math.sin(t)
    rot = np.array([[c, -s], [s, c]])
    out: np.ndarray = pts @ rot.T + np.array([x, y])
    return out


def yaw_to_quaternion(yaw: float) -> tuple[float, float, float, float]:
    """Yaw (rad) to a quaternion (x, y, z, w) about +z."""
    return (0.0, 0.0, math.sin(yaw / 2.0), math.cos(yaw / 2.0))


def quaternion_to_yaw(q: tuple[float, float, float, float]) -> float:
    """Quaternion (x, y, z, w) to yaw (rad), ignoring roll and pitch."""
    x, y, z, w = q
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
