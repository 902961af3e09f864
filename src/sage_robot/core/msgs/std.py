"""The robot's standard messages (ROS 2 equivalents named on each).

Conventions: SI units, REP 103 frames (x forward, y left, z up), stamps in seconds of
the node's clock. Planar robot: poses are (x, y, theta) and twists (v, w).
"""

from __future__ import annotations

import math
from dataclasses import field
from enum import Enum
from typing import Any

import numpy as np

from sage_robot.core.msgs.base import message

COV3_ZERO: tuple[float, ...] = (0.0,) * 9


@message("geometry_msgs/msg/Twist")
class Twist:
    """Body velocity command or estimate."""

    linear_x: float = 0.0  # m/s, forward
    angular_z: float = 0.0  # rad/s, counter-clockwise

    @property
    def is_zero(self) -> bool:
        return self.linear_x == 0.0 and self.angular_z == 0.0


@message("geometry_msgs/msg/Pose2D")
class Pose2D:
    """Planar pose: position (m) and heading (rad)."""

    x: float = 0.0
    y: float = 0.0
    theta: float = 0.0

    def as_tuple(self) -> tuple[float, float, float]:
        return (self.x, self.y, self.theta)

    def distance_to(self, other: Pose2D) -> float:
        return math.hypot(other.x - self.x, other.y - self.y)


@message("geometry_msgs/msg/PoseWithCovarianceStamped")
class PoseWithCovariance:
    """A pose estimate with its 3x3 (x, y, theta) covariance, row-major."""

    stamp: float
    frame_id: str
    pose: Pose2D
    covariance: tuple[float, ...] = COV3_ZERO


@message("geometry_msgs/msg/PoseStamped")
class PoseStamped:
    stamp: float
    frame_id: str
    pose: Pose2D


@message("nav_msgs/msg/Odometry")
class Odometry:
    """Dead-reckoned pose in ``frame_id`` (odom) of ``child_frame_id`` (base_link)."""

    stamp: float
    pose: Pose2D
    twist: Twist
    frame_id: str = "odom"
    child_frame_id: str = "base_link"
    pose_covariance: tuple[float, ...] = COV3_ZERO
    twist_covariance: tuple[float, ...] = COV3_ZERO


@message("sensor_msgs/msg/Imu")
class Imu:
    stamp: float
    angular_velocity: tuple[float, float, float]  # rad/s about x, y, z
    linear_acceleration: tuple[float, float, float]  # m/s^2
    frame_id: str = "imu_link"


class PowerStatus(str, Enum):
    UNKNOWN = "unknown"
    CHARGING = "charging"
    DISCHARGING = "discharging"
    FULL = "full"


@message("sensor_msgs/msg/BatteryState")
class BatteryState:
    stamp: float
    voltage: float  # V
    percentage: float  # 0..1, NaN when unknown (as ROS)
    status: PowerStatus = PowerStatus.DISCHARGING


@message("sensor_msgs/msg/LaserScan")
class LaserScan:
    """One lidar revolution. ``ranges`` in m; inf where nothing came back."""

    stamp: float
    frame_id: str
    angle_min: float  # rad
    angle_increment: float  # rad
    range_min: float  # m
    range_max: float  # m
    ranges: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.float32))
    scan_time: float = 0.1  # s per revolution

    @property
    def angles(self) -> np.ndarray:
        return self.angle_min + self.angle_increment * np.arange(len(self.ranges))


@message("nav_msgs/msg/OccupancyGrid")
class OccupancyGrid:
    """A map: ``data[row, col]`` with row 0 at the origin's y (bottom), values -1 (unknown) or 0..100.

    ``origin`` is the pose of cell (0, 0)'s lower-left corner in ``frame_id``.
    """

    stamp: float
    frame_id: str
    resolution: float  # m per cell
    origin: Pose2D
    data: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), dtype=np.int8))

    @property
    def width(self) -> int:
        return int(self.data.shape[1])

    @property
    def height(self) -> int:
        return int(self.data.shape[0])


@message("nav_msgs/msg/Path")
class Path:
    stamp: float
    frame_id: str
    poses: tuple[Pose2D, ...] = ()


@message("sensor_msgs/msg/CompressedImage")
class CompressedImage:
    stamp: float
    frame_id: str
    format: str  # "jpeg"
    data: bytes = b""


class Level(str, Enum):
    OK = "ok"
    WARN = "warn"
    ERROR = "error"
    STALE = "stale"


@message("diagnostic_msgs/msg/DiagnosticStatus")
class DiagnosticStatus:
    name: str
    level: Level
    message: str
    values: dict[str, str] = field(default_factory=dict)


@message("diagnostic_msgs/msg/DiagnosticArray")
class DiagnosticArray:
    stamp: float
    status: tuple[DiagnosticStatus, ...] = ()


@message("foxglove/Json")
class NodeHealth:
    """One node as the launcher knows it: state, restarts, last error, its own stats and the
    rates (Hz) of the topics it published over the last diagnostics period."""

    name: str
    state: str  # a NodeState value: created, starting, running, backoff, stopped, failed
    restarts: int = 0
    last_error: str = ""
    started_at: float | None = None
    critical: bool = False
    stats: dict[str, Any] = field(default_factory=dict)
    topics: dict[str, float] = field(default_factory=dict)


@message("foxglove/Json")
class HealthReport:
    """Every node's health (latched on ``/sage/health``; the web's ``/api/health`` shows it)."""

    stamp: float
    nodes: tuple[NodeHealth, ...] = ()


@message("std_msgs/msg/String")
class Text:
    """A line of text (speech to say, a transcript, a log line)."""

    data: str


@message()
class Utterance:
    """A ``converse`` goal that names its conversation (``Text`` goals are the robot's own):
    each session keeps its own dialogue state (``brain.base``; a message, so that a goal from
    the web's process reaches the brain's)."""

    text: str
    session: str = "robot"  # brain.base.DEFAULT_SESSION


@message("foxglove/Json")
class EStopState:
    """The latching e-stop (latched on ``/sage/estop``): engaged, and who set it last."""

    engaged: bool = False
    by: str = ""


@message("foxglove/Json")
class Event:
    """Something that happened, for people and for other nodes: ``kind`` names it."""

    stamp: float
    source: str
    kind: str  # e.g. "blocked_by_people", "arrived", "battery_low", "collision"
    message: str = ""
    data: dict[str, str] = field(default_factory=dict)
