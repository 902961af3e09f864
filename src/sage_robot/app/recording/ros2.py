"""SAGE messages ↔ standard ROS 2 messages (definitions and dict conversion).

MCAP files written with these open in Foxglove and ``ros2 bag`` tools as if a ROS 2 robot
had recorded them. Each definition is the ``.msg`` text; dependencies are appended in the
concatenated form ROS 2 bags use (``MSG: pkg/Type`` sections).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from typing import Any

import numpy as np

from sage_robot.core.geometry import quaternion_to_yaw, yaw_to_quaternion
from sage_robot.core.msgs import (
    BatteryState,
    CompressedImage,
    Imu,
    LaserScan,
    OccupancyGrid,
    Odometry,
    Path,
    Pose2D,
    PoseStamped,
    PoseWithCovariance,
    Twist,
    to_dict,
)

SEPARATOR = "=" * 80

MSG: dict[str, str] = {
    "builtin_interfaces/Time": "int32 sec\nuint32 nanosec",
    "std_msgs/Header": "builtin_interfaces/Time stamp\nstring frame_id",
    "std_msgs/String": "string data",
    "geometry_msgs/Vector3": "float64 x\nfloat64 y\nfloat64 z",
    "geometry_msgs/Point": "float64 x\nfloat64 y\nfloat64 z",
    "geometry_msgs/Quaternion": "float64 x\nfloat64 y\nfloat64 z\nfloat64 w",
    "geometry_msgs/Pose": "geometry_msgs/Point position\ngeometry_msgs/Quaternion orientation",
    "geometry_msgs/PoseStamped": "std_msgs/Header header\ngeometry_msgs/Pose pose",
    "geometry_msgs/PoseWithCovariance": "geometry_msgs/Pose pose\nfloat64[36] covariance",
    "geometry_msgs/PoseWithCovarianceStamped": (
        "std_msgs/Header header\ngeometry_msgs/PoseWithCovariance pose"
    ),
    "geometry_msgs/Twist": "geometry_msgs/Vector3 linear\ngeometry_msgs/Vector3 angular",
    "geometry_msgs/TwistWithCovariance": "geometry_msgs/Twist twist\nfloat64[36] covariance",
    "geometry_msgs/Transform": "geometry_msgs/Vector3 translation\ngeometry_msgs/Quaternion rotation",
    "geometry_msgs/TransformStamped": (
        "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/Transform transform"
    ),
    "tf2_msgs/TFMessage": "geometry_msgs/TransformStamped[] transforms",
    "nav_msgs/Odometry": (
        "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/PoseWithCovariance pose\n"
        "geometry_msgs/TwistWithCovariance twist"
    ),
    "nav_msgs/MapMetaData": (
        "builtin_interfaces/Time map_load_time\nfloat32 resolution\nuint32 width\nuint32 height\n"
        "geometry_msgs/Pose origin"
    ),
    "nav_msgs/OccupancyGrid": "std_msgs/Header header\nnav_msgs/MapMetaData info\nint8[] data",
    "nav_msgs/Path": "std_msgs/Header header\ngeometry_msgs/PoseStamped[] poses",
    "sensor_msgs/LaserScan": (
        "std_msgs/Header header\nfloat32 angle_min\nfloat32 angle_max\nfloat32 angle_increment\n"
        "float32 time_increment\nfloat32 scan_time\nfloat32 range_min\nfloat32 range_max\n"
        "float32[] ranges\nfloat32[] intensities"
    ),
    "sensor_msgs/BatteryState": (
        "std_msgs/Header header\nfloat32 voltage\nfloat32 temperature\nfloat32 current\nfloat32 charge\n"
        "float32 capacity\nfloat32 design_capacity\nfloat32 percentage\nuint8 power_supply_status\n"
        "uint8 power_supply_health\nuint8 power_supply_technology\nbool present\nfloat32[] cell_voltage\n"
        "float32[] cell_temperature\nstring location\nstring serial_number"
    ),
    "sensor_msgs/Imu": (
        "std_msgs/Header header\ngeometry_msgs/Quaternion orientation\nfloat64[9] orientation_covariance\n"
        "geometry_msgs/Vector3 angular_velocity\nfloat64[9] angular_velocity_covariance\n"
        "geometry_msgs/Vector3 linear_acceleration\nfloat64[9] linear_acceleration_covariance"
    ),
    "sensor_msgs/CompressedImage": "std_msgs/Header header\nstring format\nuint8[] data",
}


def _deps(name: str, seen: list[str]) -> None:
    for line in MSG[name].splitlines():
        field_type = line.split()[0].split("[")[0]
        if "/" in field_type and field_type not in seen:
            seen.append(field_type)
            _deps(field_type, seen)


def msgdef(name: str) -> str:
    """The full definition of ``pkg/Type`` with its dependencies, as in a ROS 2 bag."""
    deps: list[str] = []
    _deps(name, deps)
    parts = [MSG[name]] + [f"{SEPARATOR}\nMSG: {d}\n{MSG[d]}" for d in deps]
    return "\n".join(parts)


# ------------------------------------------------------------------ conversions


def _stamp(t: float) -> dict[str, int]:
    sec = math.floor(t)
    return {"sec": int(sec), "nanosec": round((t - sec) * 1e9) % 1_000_000_000}


def _header(t: float, frame: str) -> dict[str, Any]:
    return {"stamp": _stamp(t), "frame_id": frame}


def _pose(p: Pose2D) -> dict[str, Any]:
    qx, qy, qz, qw = yaw_to_quaternion(p.theta)
    return {"position": {"x": p.x, "y": p.y, "z": 0.0}, "orientation": {"x": qx, "y": qy, "z": qz, "w": qw}}


def _cov6(cov3: tuple[float, ...]) -> list[float]:
    """3x3 (x, y, yaw) covariance → ROS 6x6 (x, y, z, roll, pitch, yaw)."""
    out = [0.0] * 36
    idx = (0, 1, 5)
    for i in range(3):
        for j in range(3):
            out[idx[i] * 6 + idx[j]] = float(cov3[i * 3 + j]) if len(cov3) == 9 else 0.0
    return out


def _vec(x: float = 0.0, y: float = 0.0, z: float = 0.0) -> dict[str, float]:
    return {"x": x, "y": y, "z": z}


def _twist(t: Twist) -> dict[str, Any]:
    return {"linear": _vec(t.linear_x), "angular": _vec(z=t.angular_z)}


def odometry(m: Odometry) -> dict[str, Any]:
    return {
        "header": _header(m.stamp, m.frame_id),
        "child_frame_id": m.child_frame_id,
        "pose": {"pose": _pose(m.pose), "covariance": _cov6(m.pose_covariance)},
        "twist": {"twist": _twist(m.twist), "covariance": _cov6(m.twist_covariance)},
    }


def odom_tf(m: Odometry) -> dict[str, Any]:
    q = yaw_to_quaternion(m.pose.theta)
    return {
        "transforms": [
            {
                "header": _header(m.stamp, m.frame_id),
                "child_frame_id": m.child_frame_id,
                "transform": {
                    "translation": _vec(m.pose.x, m.pose.y),
                    "rotation": {"x": q[0], "y": q[1], "z": q[2], "w": q[3]},
                },
            }
        ]
    }


def laser_scan(m: LaserScan) -> dict[str, Any]:
    n = len(m.ranges)
    return {
        "header": _header(m.stamp, m.frame_id),
        "angle_min": m.angle_min,
        "angle_max": m.angle_min + m.angle_increment * max(n - 1, 0),
        "angle_increment": m.angle_increment,
        "time_increment": m.scan_time / n if n else 0.0,
        "scan_time": m.scan_time,
        "range_min": m.range_min,
        "range_max": m.range_max,
        "ranges": np.asarray(m.ranges, dtype=np.float32).tolist(),
        "intensities": [],
    }


def occupancy_grid(m: OccupancyGrid, as_array: bool = False) -> dict[str, Any]:
    """``as_array``: ``data`` as a flat int8 numpy array (the ROS 2 bridge's CDR codec takes it
    without a copy through a list) instead of a list (MCAP's serializer needs one)."""
    data = m.data.astype(np.int8).ravel()
    return {
        "header": _header(m.stamp, m.frame_id),
        "info": {
            "map_load_time": _stamp(m.stamp),
            "resolution": m.resolution,
            "width": m.width,
            "height": m.height,
            "origin": _pose(m.origin),
        },
        "data": data if as_array else data.tolist(),
    }


def path(m: Path) -> dict[str, Any]:
    return {
        "header": _header(m.stamp, m.frame_id),
        "poses": [{"header": _header(m.stamp, m.frame_id), "pose": _pose(p)} for p in m.poses],
    }


def pose_with_covariance(m: PoseWithCovariance) -> dict[str, Any]:
    return {
        "header": _header(m.stamp, m.frame_id),
        "pose": {"pose": _pose(m.pose), "covariance": _cov6(m.covariance)},
    }


def battery(m: BatteryState) -> dict[str, Any]:
    nan = float("nan")
    return {
        "header": _header(m.stamp, "base_link"),
        "voltage": m.voltage,
        "temperature": nan,
        "current": nan,
        "charge": nan,
        "capacity": nan,
        "design_capacity": nan,
        "percentage": m.percentage,
        "power_supply_status": {"charging": 1, "discharging": 2, "full": 4}.get(m.status.value, 0),
        "power_supply_health": 0,
        "power_supply_technology": 2,
        "present": True,
        "cell_voltage": [],
        "cell_temperature": [],
        "location": "",
        "serial_number": "",
    }


def imu(m: Imu) -> dict[str, Any]:
    unknown = [-1.0] + [0.0] * 8  # orientation not estimated (REP 145)
    return {
        "header": _header(m.stamp, m.frame_id),
        "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0},
        "orientation_covariance": unknown,
        "angular_velocity": _vec(*m.angular_velocity),
        "angular_velocity_covariance": [0.0] * 9,
        "linear_acceleration": _vec(*m.linear_acceleration),
        "linear_acceleration_covariance": [0.0] * 9,
    }


def compressed_image(m: CompressedImage) -> dict[str, Any]:
    return {"header": _header(m.stamp, m.frame_id), "format": m.format, "data": m.data}


def twist(m: Twist) -> dict[str, Any]:
    return _twist(m)


def pose_stamped(m: PoseStamped) -> dict[str, Any]:
    return {"header": _header(m.stamp, m.frame_id), "pose": _pose(m.pose)}


def pose_tf(m: PoseStamped, child_frame_id: str) -> dict[str, Any]:
    """A tf2_msgs/TFMessage of one transform: ``m`` is the pose of ``child_frame_id`` in
    ``m.frame_id`` (e.g. the map → odom correction)."""
    pose = _pose(m.pose)
    return {
        "transforms": [
            {
                "header": _header(m.stamp, m.frame_id),
                "child_frame_id": child_frame_id,
                "transform": {"translation": pose["position"], "rotation": pose["orientation"]},
            }
        ]
    }


# ------------------------------------------------------------------ ROS 2 → SAGE


def _finite(*values: Any) -> tuple[float, ...]:
    out = tuple(float(v) for v in values)
    if not all(math.isfinite(v) for v in out):
        raise ValueError(f"non-finite value in {out}")
    return out


def twist_from_ros(d: dict[str, Any]) -> Twist:
    """geometry_msgs/Twist → SAGE's planar Twist (linear.x, angular.z; the rest is ignored)."""
    linear_x, angular_z = _finite(d["linear"]["x"], d["angular"]["z"])
    return Twist(linear_x, angular_z)


def pose_stamped_from_ros(d: dict[str, Any]) -> PoseStamped:
    """geometry_msgs/PoseStamped → SAGE's planar PoseStamped (x, y and the yaw of the quaternion)."""
    p, q = d["pose"]["position"], d["pose"]["orientation"]
    x, y = _finite(p["x"], p["y"])
    qx, qy, qz, qw = _finite(q["x"], q["y"], q["z"], q["w"])
    stamp = d["header"]["stamp"]
    t = int(stamp["sec"]) + int(stamp["nanosec"]) * 1e-9
    return PoseStamped(t, str(d["header"]["frame_id"]), Pose2D(x, y, quaternion_to_yaw((qx, qy, qz, qw))))


def as_json_string(m: Any) -> dict[str, Any]:
    return {"data": json.dumps(to_dict(m))}


# SAGE type → (ROS 2 type, converter). Anything else is recorded as std_msgs/String JSON.
CONVERTERS: dict[type, tuple[str, Callable[[Any], dict[str, Any]]]] = {
    Odometry: ("nav_msgs/Odometry", odometry),
    LaserScan: ("sensor_msgs/LaserScan", laser_scan),
    OccupancyGrid: ("nav_msgs/OccupancyGrid", occupancy_grid),
    Path: ("nav_msgs/Path", path),
    PoseWithCovariance: ("geometry_msgs/PoseWithCovarianceStamped", pose_with_covariance),
    BatteryState: ("sensor_msgs/BatteryState", battery),
    Imu: ("sensor_msgs/Imu", imu),
    CompressedImage: ("sensor_msgs/CompressedImage", compressed_image),
    Twist: ("geometry_msgs/Twist", twist),
}
JSON_TYPE = "std_msgs/String"


def convert(msg: Any) -> tuple[str, dict[str, Any]]:
    """(ROS 2 type, message dict) for a SAGE message."""
    ros_type, fn = CONVERTERS.get(type(msg), (JSON_TYPE, as_json_string))
    return ros_type, fn(msg)
