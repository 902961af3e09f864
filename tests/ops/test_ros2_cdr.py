"""ROS 2 CDR and rmw_zenoh names: checked against independent implementations and published values.

- CDR bytes from the bridge's codec (rosbags, on its built-in Jazzy definitions) equal those of
  mcap-ros2-support's serializer (driven by recording.ros2's .msg text) for every type sent.
- Type hashes and key expressions equal values published by ROS 2 users and rmw_zenoh's docs.
- The attachment equals what Zenoh's own serializer makes of (int64, int64, bytes), which is what
  rmw_zenoh_cpp's ``zenoh::ext::Serializer`` writes.
"""

import math
from typing import Any

import numpy as np
import pytest
import zenoh.ext
from mcap_ros2._dynamic import serialize_dynamic

from sage_robot.app import ros2_cdr
from sage_robot.app.recording import ros2
from sage_robot.app.rmw_zenoh import (
    ATTACHMENT_SIZE,
    Attachment,
    Durability,
    Entity,
    NodeInfo,
    Qos,
    Reliability,
    liveliness_token,
    qos_keyexpr,
    topic_keyexpr,
)
from sage_robot.core.mapio import read_map
from sage_robot.core.msgs import (
    BatteryState,
    CompressedImage,
    Imu,
    LaserScan,
    Odometry,
    Path,
    Pose2D,
    PoseStamped,
    PoseWithCovariance,
    Twist,
)
from sage_robot.core.msgs.std import PowerStatus

COV = tuple(float(i) / 10 for i in range(9))
SCAN = LaserScan(
    12.345678, "laser", -math.pi, math.tau / 360, 0.15, 12.0,
    np.where(np.arange(360) % 7 == 0, np.inf, np.linspace(0.2, 11.0, 360)).astype(np.float32),
)  # fmt: skip
ODOM = Odometry(3.25, Pose2D(1.5, -2.0, 0.75), Twist(0.3, -0.2), pose_covariance=COV, twist_covariance=COV)
MAP_ODOM = PoseStamped(4.0, "map", Pose2D(0.1, 0.2, -0.05))

# (what is sent, ROS 2 type, the recording module's dict for it)
CASES = [
    ("scan", "sensor_msgs/LaserScan", ros2.laser_scan(SCAN)),
    ("odom", "nav_msgs/Odometry", ros2.odometry(ODOM)),
    ("tf odom", "tf2_msgs/TFMessage", ros2.odom_tf(ODOM)),
    ("tf map", "tf2_msgs/TFMessage", ros2.pose_tf(MAP_ODOM, "odom")),
    ("imu", "sensor_msgs/Imu", ros2.imu(Imu(1.0, (0.01, -0.02, 0.3), (0.1, 0.0, 9.81)))),
    ("battery", "sensor_msgs/BatteryState",
     ros2.battery(BatteryState(7.5, 15.1, 0.62, PowerStatus.CHARGING))),
    ("amcl", "geometry_msgs/PoseWithCovarianceStamped",
     ros2.pose_with_covariance(PoseWithCovariance(9.0, "map", Pose2D(3.0, 4.0, 1.0), COV))),
    ("plan", "nav_msgs/Path",
     ros2.path(Path(2.0, "map", (Pose2D(0, 0, 0), Pose2D(1.0, 0.5, 0.3), Pose2D(2, 1, 0.6))))),
    ("empty plan", "nav_msgs/Path", ros2.path(Path(2.0, "map", ()))),
    ("cmd_vel", "geometry_msgs/Twist", ros2.twist(Twist(0.4, -1.1))),
    ("goal", "geometry_msgs/PoseStamped", ros2.pose_stamped(PoseStamped(5.5, "map", Pose2D(-1.0, 2.0, 2.5)))),
    ("image", "sensor_msgs/CompressedImage",
     ros2.compressed_image(CompressedImage(1.5, "camera", "jpeg", b"\xff\xd8abc"))),
]  # fmt: skip


def mcap_encode(ros_type: str, value: dict[str, Any]) -> bytes:
    return serialize_dynamic(ros_type, ros2.msgdef(ros_type))[ros_type](value)


@pytest.mark.parametrize(("what", "ros_type", "value"), CASES, ids=[c[0] for c in CASES])
def test_cdr_bytes_equal_the_independent_serializer(what, ros_type, value):
    ours = ros2_cdr.encode(ros_type, value)
    assert ours[:4] == ros2_cdr.ENCAPSULATION_CDR_LE
    assert ours == mcap_encode(ros_type, value), what


@pytest.mark.parametrize(("what", "ros_type", "value"), CASES, ids=[c[0] for c in CASES])
def test_cdr_round_trip(what, ros_type, value):
    data = ros2_cdr.encode(ros_type, value)
    decoded = ros2_cdr.decode(ros_type, data)
    assert ros2_cdr.encode(ros_type, decoded) == data, what  # bytes -> dict -> the same bytes
    if "header" in value:
        assert decoded["header"] == value["header"]


def test_real_map_encodes_as_the_independent_serializer(shared_data):
    grid = read_map(shared_data("maps/tb3-sandbox/tb3_sandbox.yaml"))  # a real Nav2/TurtleBot3 map
    value = ros2.occupancy_grid(grid)
    data = ros2_cdr.encode("nav_msgs/OccupancyGrid", value)
    assert data == mcap_encode("nav_msgs/OccupancyGrid", value)
    assert ros2_cdr.encode("nav_msgs/OccupancyGrid", ros2.occupancy_grid(grid, as_array=True)) == data
    back = ros2_cdr.decode("nav_msgs/OccupancyGrid", data)
    assert (back["info"]["width"], back["info"]["height"]) == (grid.width, grid.height)
    assert np.array_equal(np.asarray(back["data"], np.int8).reshape(grid.data.shape), grid.data)


def test_scan_values_survive_the_wire():
    back = ros2_cdr.decode(
        "sensor_msgs/LaserScan", ros2_cdr.encode("sensor_msgs/LaserScan", ros2.laser_scan(SCAN))
    )
    assert np.array_equal(np.asarray(back["ranges"], np.float32), SCAN.ranges)  # inf included
    assert back["angle_min"] == pytest.approx(-math.pi, abs=1e-6)
    assert back["header"] == {"stamp": {"sec": 12, "nanosec": 345678000}, "frame_id": "laser"}


def test_incoming_twist_and_goal_decode_to_sage_messages():
    twist = ros2.twist_from_ros(
        ros2_cdr.decode(
            "geometry_msgs/Twist", mcap_encode("geometry_msgs/Twist", ros2.twist(Twist(0.25, -0.5)))
        )
    )
    assert twist == Twist(0.25, -0.5)
    sent = PoseStamped(7.25, "map", Pose2D(1.0, -2.0, 2.0))
    got = ros2.pose_stamped_from_ros(
        ros2_cdr.decode(
            "geometry_msgs/PoseStamped", mcap_encode("geometry_msgs/PoseStamped", ros2.pose_stamped(sent))
        )
    )
    assert (got.frame_id, got.stamp) == ("map", 7.25)
    assert (got.pose.x, got.pose.y, got.pose.theta) == pytest.approx((1.0, -2.0, 2.0))


def test_trailing_padding_announced_in_the_options_is_accepted():
    # A DDS/XTypes writer may pad the message to 4 bytes and say so in the options' low bits.
    plain = ros2_cdr.encode("std_msgs/String", {"data": "hello"})  # 4 + 4 + 6 bytes
    padded = plain[:3] + bytes([3]) + plain[4:] + bytes(3)
    assert ros2_cdr.decode("std_msgs/String", padded) == {"data": "hello"}
    with pytest.raises(ros2_cdr.CdrError, match="cannot decode 22 bytes"):
        ros2_cdr.decode("std_msgs/String", plain + bytes(8))  # more than alignment: refused


def test_bad_bytes_give_one_line_errors():
    with pytest.raises(ros2_cdr.CdrError, match="not CDR"):
        ros2_cdr.decode("geometry_msgs/Twist", b"{}")
    with pytest.raises(ros2_cdr.CdrError, match="cannot decode 20 bytes"):
        ros2_cdr.decode(
            "geometry_msgs/Twist", ros2_cdr.encode("geometry_msgs/Twist", ros2.twist(Twist(1, 1)))[:20]
        )
    with pytest.raises(ros2_cdr.CdrError, match="unknown ROS 2 type"):
        ros2_cdr.type_hash("sage_msgs/Nothing")
    with pytest.raises(ros2_cdr.CdrError, match="missing field 'angular'"):
        ros2_cdr.encode("geometry_msgs/Twist", {"linear": {"x": 0.0, "y": 0.0, "z": 0.0}})
    nan_twist = {"linear": {"x": float("nan"), "y": 0.0, "z": 0.0}, "angular": {"x": 0.0, "y": 0.0, "z": 0.0}}
    with pytest.raises(ValueError, match="non-finite"):
        ros2.twist_from_ros(nan_twist)


# Published values: `ros2 topic info -v` printouts (Twist in the ROS 2 docs' topic tutorial,
# OccupancyGrid seen by rviz); rmw_zenoh's docs/design.md (String); CARLA's ROS 2 native interface,
# CdrTopicInfo.h (Imu, Odometry, TFMessage, PoseStamped); zenoh-based Rust ROS 2 crates (LaserScan).
PUBLISHED_HASHES = {
    "geometry_msgs/msg/Twist": "RIHS01_9c45bf16fe0983d80e3cfe750d6835843d265a9a6c46bd2e609fcddde6fb8d2a",
    "std_msgs/msg/String": "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18",
    "sensor_msgs/msg/Imu": "RIHS01_7d9a00ff131080897a5ec7e26e315954b8eae3353c3f995c55faf71574000b5b",
    "nav_msgs/msg/Odometry": "RIHS01_3cc97dc7fb7502f8714462c526d369e35b603cfc34d946e3f2eda2766dfec6e0",
    "tf2_msgs/msg/TFMessage": "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087",
    "nav_msgs/msg/OccupancyGrid": "RIHS01_8d348150c12913a31ee0ec170fbf25089e4745d17035792a1ba94d6f0bc0cfc7",
    "sensor_msgs/msg/LaserScan": "RIHS01_64c191398013af96509d518dac71d5164f9382553fce5c1f8cca5be7924bd828",
    "geometry_msgs/msg/PoseStamped": "RIHS01_10f3786d7d40fd2b54367835614bff85d4ad3b5dab62bf8bca0cc232d73b4cd8",  # noqa: E501
}


@pytest.mark.parametrize("ros_type", sorted(PUBLISHED_HASHES))
def test_type_hashes_equal_published_values(ros_type):
    assert ros2_cdr.type_hash(ros_type) == PUBLISHED_HASHES[ros_type]


def test_key_expression_and_tokens_equal_rmw_zenohs():
    # rmw_zenoh docs/design.md: the talker of demo_nodes_cpp (depth 7) and its data key.
    string = "std_msgs/String"
    dds, h = ros2_cdr.dds_type_name(string), ros2_cdr.type_hash(string)
    assert (
        topic_keyexpr(0, "/chatter", dds, h)
        == f"0/chatter/std_msgs::msg::dds_::String_/{PUBLISHED_HASHES['std_msgs/msg/String']}"
    )
    talker = NodeInfo(0, "8b20917502ee955ac4476e0266340d5c", 0, "talker")
    assert liveliness_token(talker, 10, Entity.PUBLISHER, "/chatter", dds, h, Qos(depth=7)) == (
        "@ros2_lv/0/8b20917502ee955ac4476e0266340d5c/0/10/MP/%/%/talker/%chatter/"
        f"std_msgs::msg::dds_::String_/{h}/::,7:,:,:,,"
    )
    listener = NodeInfo(0, "aac3178e146ba6f1fc6e6a4085e77f21", 0, "listener")
    assert (
        liveliness_token(listener, 0, Entity.NODE)
        == "@ros2_lv/0/aac3178e146ba6f1fc6e6a4085e77f21/0/0/NN/%/%/listener"
    )
    # Namespaced topics keep their inner slashes in the data key and mangle them in tokens.
    imu = "sensor_msgs/Imu"
    assert (
        topic_keyexpr(7, "/imu/data", ros2_cdr.dds_type_name(imu), "H")
        == "7/imu/data/sensor_msgs::msg::dds_::Imu_/H"
    )
    assert "/%imu%data/" in liveliness_token(listener, 3, Entity.SUBSCRIPTION, "/imu/data", "T", "H", Qos())


def test_qos_strings():
    assert qos_keyexpr(Qos()) == "::,10:,:,:,,"
    assert qos_keyexpr(Qos(Reliability.BEST_EFFORT, Durability.VOLATILE, 5)) == "2::,5:,:,:,,"
    assert qos_keyexpr(Qos(Reliability.RELIABLE, Durability.TRANSIENT_LOCAL, 1)) == ":1:,1:,:,:,,"
    assert qos_keyexpr(Qos(depth=42)) == "::,:,:,:,,"  # rmw_zenoh's default depth is left out


def test_attachment_is_zenohs_serialization_of_seq_stamp_gid():
    gid = bytes(range(16))
    ours = Attachment(5, 1_700_000_000_123_456_789, gid).encode()
    theirs = zenoh.ext.z_serialize((zenoh.ext.Int64(5), zenoh.ext.Int64(1_700_000_000_123_456_789), gid))
    assert ours == theirs.to_bytes()
    assert len(ours) == ATTACHMENT_SIZE
    assert Attachment.decode(ours) == Attachment(5, 1_700_000_000_123_456_789, gid)
    with pytest.raises(ValueError, match="expected 33 bytes"):
        Attachment.decode(ours[:-1])
