"""Simulator truth messages: people, the speaker's bearing, low obstacles.

Only the simulator publishes these (tests, benchmarks and the web's debug views read
them); nodes that also run on the real robot never depend on them. Map frame, metres,
radians (REP 103: x forward/east, y left/north, theta counter-clockwise).
"""

from __future__ import annotations

import math

from sage_robot.core.msgs.base import message


@message()
class Person:
    """One simulated pedestrian: a body circle of ``radius_m`` at (x, y), facing ``theta``."""

    id: int
    x: float  # m, map frame
    y: float  # m, map frame
    theta: float = 0.0  # rad, walking/facing direction
    speed_mps: float = 0.0  # m/s, current walking speed
    behaviour: str = "walker"  # walker | stander | group | approacher
    radius_m: float = 0.25  # m, body circle used for collisions


@message("foxglove/SceneUpdate")
class People:
    """Every simulated person at ``stamp`` (s, simulated clock)."""

    stamp: float
    people: tuple[Person, ...] = ()


@message()
class SpeakerBearing:
    """Where the simulated speaker stands relative to the robot, for the simulated DOA.

    ``angle_deg`` uses the seed's DOA convention (XVF3800 as mounted on SAGE):
    0° behind, 90° left, 180° front, 270° right. ``present`` is False when nobody is
    within range; the angle is then 0 and means nothing.
    """

    stamp: float
    present: bool
    angle_deg: float = 0.0  # [0, 360)
    distance_m: float = 0.0
    person_id: int = -1


def bearing_to_doa_deg(bearing_rad: float) -> float:
    """A bearing in the robot frame (0 = ahead, + = left, rad) → the seed's DOA angle (deg)."""
    return (180.0 - math.degrees(bearing_rad)) % 360.0


def doa_deg_to_bearing(angle_deg: float) -> float:
    """The inverse of :func:`bearing_to_doa_deg`: DOA degrees → robot-frame bearing in (-pi, pi]."""
    b = math.radians(180.0 - angle_deg)
    return math.atan2(math.sin(b), math.cos(b))


@message()
class LowObstacle:
    """A box below the lidar's scan plane (a bench, a cart): the robot collides with it
    but the lidar cannot see it. ``size`` is (length along ``yaw``, depth) in m."""

    name: str
    x: float  # m, centre, map frame
    y: float  # m
    length_m: float  # m, along yaw
    depth_m: float  # m, across yaw
    yaw: float = 0.0  # rad
    height_m: float = 0.45  # m, top of the box above the floor
    kind: str = "bench"
