"""MCAP round trip with standard ROS 2 schemas; the Foxglove live server."""

import asyncio
import json
from typing import Any

import numpy as np
import pytest

from sage_robot.app.recording.mcap_io import McapRecorder, read_mcap
from sage_robot.app.recording.nodes import RECORD_PATH, FoxgloveNode, RecorderNode
from sage_robot.core.bus import Bus
from sage_robot.core.clock import SimClock
from sage_robot.core.config import load_profile
from sage_robot.core.msgs import (
    BatteryState,
    Event,
    Imu,
    LaserScan,
    OccupancyGrid,
    Odometry,
    Path,
    Pose2D,
    PoseWithCovariance,
    Twist,
)
from sage_robot.core.msgs.voice import Phase, UiState
from sage_robot.core.node import NodeContext

MESSAGES = [
    (
        "/scan",
        LaserScan(1.5, "laser", -np.pi, np.pi / 180, 0.15, 12.0, np.linspace(0.5, 5, 360, dtype=np.float32)),
    ),
    (
        "/odom",
        Odometry(
            1.6, Pose2D(1.0, 2.0, 0.5), Twist(0.3, 0.1), pose_covariance=tuple(float(i) for i in range(9))
        ),
    ),
    (
        "/map",
        OccupancyGrid(1.7, "map", 0.05, Pose2D(-1, -2, 0), np.array([[0, 100], [-1, 0]], dtype=np.int8)),
    ),
    ("/cmd_vel", Twist(0.4, -0.2)),
    ("/battery_state", BatteryState(1.8, 15.2, 0.7)),
    ("/plan", Path(1.9, "map", (Pose2D(0, 0, 0), Pose2D(1, 1, 0.7)))),
    ("/amcl_pose", PoseWithCovariance(2.0, "map", Pose2D(3, 4, -0.3), (0.01, 0, 0, 0, 0.01, 0, 0, 0, 0.002))),
    ("/imu/data", Imu(2.1, (0.0, 0.0, 0.1), (0.0, 0.0, 9.81))),
    ("/sage/ui_state", UiState(Phase.SPEAKING, asr_final="take me to the cafe", tts_viseme=0.4)),
    ("/sage/events", Event(2.2, "nav", "arrived", "at the cafe", {"place": "GUELLY_DELLY"})),
]


def test_mcap_round_trip_with_ros2_schemas(tmp_path):
    path = tmp_path / "run.mcap"
    rec = McapRecorder(path)
    for i, (topic, msg) in enumerate(MESSAGES):
        rec.write(topic, msg, 10.0 + i)
    rec.close()

    # Read with the plain mcap reader: standard ROS 2 schema names, ros2msg encoding, CDR messages.
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    schemas = {s.name: s.encoding for s in summary.schemas.values()}
    assert schemas["sensor_msgs/msg/LaserScan"] == "ros2msg"
    assert {
        "nav_msgs/msg/Odometry",
        "tf2_msgs/msg/TFMessage",
        "nav_msgs/msg/OccupancyGrid",
        "geometry_msgs/msg/Twist",
        "std_msgs/msg/String",
    } <= set(schemas)
    assert all(c.message_encoding == "cdr" for c in summary.channels.values())

    back = {topic: msg for topic, _, msg in read_mcap(path)}
    for topic, msg in MESSAGES:
        got = back[topic]
        if isinstance(msg, (Odometry, PoseWithCovariance)):
            assert got.pose.x == pytest.approx(msg.pose.x)
            assert got.pose.theta == pytest.approx(msg.pose.theta)
        elif isinstance(msg, LaserScan):
            assert np.allclose(got.ranges, msg.ranges)
        elif isinstance(msg, BatteryState):
            assert got.voltage == pytest.approx(msg.voltage)
        elif isinstance(msg, Imu):
            assert got.linear_acceleration == pytest.approx(msg.linear_acceleration)
        elif isinstance(msg, OccupancyGrid):
            assert np.array_equal(got.data, msg.data)
            assert got.resolution == pytest.approx(msg.resolution)
            assert got.origin == msg.origin
        elif isinstance(msg, Path):
            assert len(got.poses) == 2
            assert got.poses[1].theta == pytest.approx(0.7)
        else:
            assert got == msg


def test_broken_file_is_a_clear_error(tmp_path):
    from sage_robot.core.errors import SageError

    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"not an mcap file at all")
    with pytest.raises(SageError, match="not a readable MCAP"):
        list(read_mcap(bad))


async def test_recorder_node_records_bus_traffic(tmp_path):
    clock = SimClock()
    bus = Bus(clock)
    ctx = NodeContext(bus, clock, load_profile())
    ctx.resources[RECORD_PATH] = tmp_path / "live.mcap"
    node = RecorderNode(ctx)
    await node.setup()
    for i in range(5):
        bus.publish("/odom", Odometry(clock.now(), Pose2D(i, 0, 0), Twist(1, 0)))
        bus.publish("/not_recorded", Twist(0, 0))
        await clock.step(0.1)
    await node.teardown()
    topics = [t for t, _, _ in read_mcap(tmp_path / "live.mcap")]
    assert topics.count("/odom") == 5
    assert "/not_recorded" not in topics


async def _foxglove_node() -> tuple[Bus, FoxgloveNode]:
    """A Foxglove node on a bus of its own, listening on a free loopback port."""
    clock = SimClock()
    bus = Bus(clock)
    ctx = NodeContext(
        bus, clock, load_profile(None, {"ops": {"foxglove_host": "127.0.0.1", "foxglove_port": 0}})
    )
    node = FoxgloveNode(ctx)
    await node.setup()
    return bus, node


def _foxglove_viewer(node: FoxgloveNode) -> Any:
    import websockets
    from websockets.typing import Subprotocol

    protocols = [Subprotocol("foxglove.sdk.v1"), Subprotocol("foxglove.websocket.v1")]
    return websockets.connect(f"ws://127.0.0.1:{node.port}", subprotocols=protocols)


async def test_foxglove_server_advertises_live_topics():
    bus, node = await _foxglove_node()
    try:
        bus.publish("/odom", Odometry(0.0, Pose2D(1, 2, 0), Twist()))
        async with _foxglove_viewer(node) as ws:
            seen: dict[str, dict[str, Any]] = {}
            for _ in range(20):  # bounded: serverInfo, advertise, ...
                raw = await asyncio.wait_for(ws.recv(), 5)
                if isinstance(raw, str):
                    msg = json.loads(raw)
                    seen[msg["op"]] = msg
                if "advertise" in seen:
                    break
        assert "serverInfo" in seen
        channels = {c["topic"]: c for c in seen["advertise"]["channels"]}
        assert channels["/odom"]["schemaName"] == "nav_msgs/msg/Odometry"
        assert channels["/odom"]["schemaEncoding"] == "ros2msg"
        assert node.stats()["errors"] == 0
    finally:
        await node.teardown()


async def test_foxglove_converts_a_topic_only_for_a_viewer_who_subscribed_and_wants_all_while_watched():
    bus, node = await _foxglove_node()
    try:
        bus.publish("/odom", Odometry(0.0, Pose2D(1, 2, 0), Twist()))  # advertises the channel
        assert node._release_all is None  # nobody watches: other processes' topics stay away
        async with _foxglove_viewer(node) as ws:
            channels: dict[str, int] = {}
            for _ in range(20):  # bounded: serverInfo, advertise, ...
                raw = await asyncio.wait_for(ws.recv(), 5)
                if isinstance(raw, str) and json.loads(raw)["op"] == "advertise":
                    channels = {c["topic"]: c["id"] for c in json.loads(raw)["channels"]}
                    break
            assert node.gate.viewers == 1
            assert node._release_all is not None
            sent = node.sent
            bus.publish("/odom", Odometry(0.1, Pose2D(1, 2, 0), Twist()))
            assert node.sent == sent  # advertised, not subscribed: not converted
            subscribe = {"op": "subscribe", "subscriptions": [{"id": 7, "channelId": channels["/odom"]}]}
            await ws.send(json.dumps(subscribe))

            async def data() -> bytes | None:
                bus.publish("/odom", Odometry(0.2, Pose2D(1, 2, 0), Twist()))  # until the subscription took
                try:
                    raw = await asyncio.wait_for(ws.recv(), 0.2)
                except asyncio.TimeoutError:
                    return None
                return raw if isinstance(raw, bytes) and raw[:1] == b"\x01" else None  # MessageData

            for _ in range(50):  # bounded: 10 s
                if await data():
                    break
            else:
                raise AssertionError("no /odom message reached the subscribed viewer")
            assert node.sent > sent
        for _ in range(100):  # bounded: the gate sees the viewer go
            if node.gate.viewers == 0:
                break
            await asyncio.sleep(0.05)
        assert node.gate.viewers == 0
        assert node._release_all is None
        assert node.stats()["errors"] == 0
    finally:
        await node.teardown()
