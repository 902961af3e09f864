"""MCAP files with standard ROS 2 schemas: write SAGE topics, read them back as SAGE messages."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

import numpy as np

from sage_robot.app.recording import ros2
from sage_robot.core.errors import SageError
from sage_robot.core.geometry import quaternion_to_yaw
from sage_robot.core.msgs import (
    BatteryState,
    CompressedImage,
    Imu,
    LaserScan,
    OccupancyGrid,
    Odometry,
    Pose2D,
    PoseWithCovariance,
    PowerStatus,
    Twist,
    from_dict,
)
from sage_robot.core.msgs import (
    Path as PathMsg,
)

PROFILE = "ros2"
NS = 1_000_000_000


def _ros_name(t: str) -> str:
    pkg, name = t.split("/")
    return f"{pkg}/msg/{name}"


class McapRecorder:
    """Write SAGE messages as ROS 2 CDR into an MCAP file; schemas registered on first use."""

    def __init__(self, path: str | Path) -> None:
        from mcap_ros2.writer import Writer

        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file: IO[bytes] = open(self.path, "wb")  # noqa: SIM115 - closed in close()
        self._writer = Writer(self._file)
        self._schemas: dict[str, Any] = {}
        self.counts: dict[str, int] = {}

    def write(self, topic: str, msg: Any, t: float) -> None:
        ros_type, data = ros2.convert(msg)
        schema = self._schemas.get(ros_type)
        if schema is None:
            schema = self._schemas[ros_type] = self._writer.register_msgdef(
                _ros_name(ros_type), ros2.msgdef(ros_type)
            )
        stamp = int(t * NS)
        self._writer.write_message(topic, schema, data, log_time=stamp, publish_time=stamp)
        self.counts[topic] = self.counts.get(topic, 0) + 1
        if isinstance(msg, Odometry):  # the odom → base_link transform, as ROS robots publish it
            self.write("/tf", _TfWrap(msg), t)

    def close(self) -> None:
        self._writer.finish()
        self._file.close()


class _TfWrap:
    def __init__(self, odom: Odometry) -> None:
        self.odom = odom


ros2.CONVERTERS[_TfWrap] = ("tf2_msgs/TFMessage", lambda w: ros2.odom_tf(w.odom))


# ------------------------------------------------------------------ reading back


def _t(stamp: Any) -> float:
    t: float = stamp.sec + stamp.nanosec / NS
    return t


def _pose2d(p: Any) -> Pose2D:
    q = p.orientation
    return Pose2D(p.position.x, p.position.y, quaternion_to_yaw((q.x, q.y, q.z, q.w)))


def _cov3(c: Any) -> tuple[float, ...]:
    idx = (0, 1, 5)
    return tuple(float(c[idx[i] * 6 + idx[j]]) for i in range(3) for j in range(3))


def _from_ros(ros_type: str, m: Any) -> Any:
    if ros_type == "nav_msgs/msg/Odometry":
        tw = m.twist.twist
        return Odometry(
            _t(m.header.stamp),
            _pose2d(m.pose.pose),
            Twist(tw.linear.x, tw.angular.z),
            m.header.frame_id,
            m.child_frame_id,
            _cov3(m.pose.covariance),
            _cov3(m.twist.covariance),
        )
    if ros_type == "sensor_msgs/msg/LaserScan":
        return LaserScan(
            _t(m.header.stamp),
            m.header.frame_id,
            m.angle_min,
            m.angle_increment,
            m.range_min,
            m.range_max,
            np.asarray(m.ranges, dtype=np.float32),
            m.scan_time,
        )
    if ros_type == "nav_msgs/msg/OccupancyGrid":
        data = np.asarray(m.data, dtype=np.int8).reshape(m.info.height, m.info.width)
        return OccupancyGrid(
            _t(m.header.stamp), m.header.frame_id, m.info.resolution, _pose2d(m.info.origin), data
        )
    if ros_type == "nav_msgs/msg/Path":
        return PathMsg(_t(m.header.stamp), m.header.frame_id, tuple(_pose2d(p.pose) for p in m.poses))
    if ros_type == "geometry_msgs/msg/PoseWithCovarianceStamped":
        return PoseWithCovariance(
            _t(m.header.stamp), m.header.frame_id, _pose2d(m.pose.pose), _cov3(m.pose.covariance)
        )
    if ros_type == "sensor_msgs/msg/BatteryState":
        status = {1: PowerStatus.CHARGING, 2: PowerStatus.DISCHARGING, 4: PowerStatus.FULL}.get(
            m.power_supply_status, PowerStatus.UNKNOWN
        )
        return BatteryState(_t(m.header.stamp), m.voltage, m.percentage, status)
    if ros_type == "sensor_msgs/msg/Imu":
        a, g = m.linear_acceleration, m.angular_velocity
        return Imu(_t(m.header.stamp), (g.x, g.y, g.z), (a.x, a.y, a.z), m.header.frame_id)
    if ros_type == "sensor_msgs/msg/CompressedImage":
        return CompressedImage(_t(m.header.stamp), m.header.frame_id, m.format, bytes(m.data))
    if ros_type == "geometry_msgs/msg/Twist":
        return Twist(m.linear.x, m.angular.z)
    if ros_type == "std_msgs/msg/String":
        return from_dict(json.loads(m.data))
    return None  # e.g. /tf: derived from /odom, not replayed


def read_mcap(path: str | Path) -> Iterator[tuple[str, float, Any]]:
    """(topic, log time s, SAGE message) for every message SAGE knows how to rebuild."""
    from mcap.exceptions import McapError
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    try:
        with open(path, "rb") as f:
            reader = make_reader(f, decoder_factories=[DecoderFactory()])
            for schema, channel, message, decoded in reader.iter_decoded_messages(log_time_order=True):
                msg = _from_ros(schema.name if schema else "", decoded)
                if msg is not None:
                    yield channel.topic, message.log_time / NS, msg
    except FileNotFoundError:
        raise SageError(f"{path}: recording not found") from None
    except (McapError, ValueError, EOFError) as exc:
        raise SageError(f"{path}: not a readable MCAP recording ({exc})") from None
