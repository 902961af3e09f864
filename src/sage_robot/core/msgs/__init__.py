"""Messages: frozen dataclasses, JSON codec, registry. Area modules add their own types
(and are imported here so that every type is registered for decoding)."""

from sage_robot.core.msgs import kb, nav, sim, voice  # noqa: F401  (registers area messages)
from sage_robot.core.msgs.base import REGISTRY, ROS_TYPES, from_dict, message, to_dict
from sage_robot.core.msgs.std import (
    BatteryState,
    CompressedImage,
    DiagnosticArray,
    DiagnosticStatus,
    EStopState,
    Event,
    Imu,
    LaserScan,
    Level,
    OccupancyGrid,
    Odometry,
    Path,
    Pose2D,
    PoseStamped,
    PoseWithCovariance,
    PowerStatus,
    Text,
    Twist,
)

__all__ = [
    "REGISTRY",
    "ROS_TYPES",
    "BatteryState",
    "CompressedImage",
    "DiagnosticArray",
    "DiagnosticStatus",
    "EStopState",
    "Event",
    "Imu",
    "LaserScan",
    "Level",
    "OccupancyGrid",
    "Odometry",
    "Path",
    "Pose2D",
    "PoseStamped",
    "PoseWithCovariance",
    "PowerStatus",
    "Text",
    "Twist",
    "from_dict",
    "message",
    "to_dict",
]
