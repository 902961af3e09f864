"""The ROS 2 bridge on real Zenoh sessions over loopback (no ROS 2 install: the test plays the ROS
node with a plain Zenoh session on rmw_zenoh's key expressions, as an rmw_zenoh node would)."""

import asyncio
import math
import socket
from collections.abc import Callable

import numpy as np
import pytest
import zenoh
import zenoh.ext
from mcap_ros2._dynamic import serialize_dynamic

from sage_robot.app import ros2_cdr
from sage_robot.app.recording import ros2
from sage_robot.app.rmw_zenoh import Attachment
from sage_robot.app.ros2_bridge import ROS2_BRIDGE_SETTINGS, Ros2BridgeNode, Ros2BridgeSettings
from sage_robot.core import topics
from sage_robot.core.bus import Bus
from sage_robot.core.clock import WallClock
from sage_robot.core.config import load_profile
from sage_robot.core.errors import ConfigError
from sage_robot.core.mapio import read_map
from sage_robot.core.msgs import EStopState, LaserScan, OccupancyGrid, Pose2D, PoseStamped, Twist
from sage_robot.core.node import NodeContext

from ..support.waits import until

DOMAIN = 3
RESEND_S = 0.05  # the test re-sends until the other side's declarations have propagated
MAX_TRIES = 200  # bound on re-sends (10 s)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def key(topic: str, ros_type: str) -> str:
    return f"{DOMAIN}/{topic.strip('/')}/{ros2_cdr.dds_type_name(ros_type)}/{ros2_cdr.type_hash(ros_type)}"


def zenoh_config(mode: str, connect: str = "", listen: str = "") -> zenoh.Config:
    config = zenoh.Config()
    config.insert_json5("mode", f'"{mode}"')
    config.insert_json5("connect/endpoints", f'["{connect}"]' if connect else "[]")
    config.insert_json5("listen/endpoints", f'["{listen}"]' if listen else "[]")
    config.insert_json5("scouting/multicast/enabled", "false")
    return config


def make_bridge(connect: tuple[str, ...], listen: tuple[str, ...]) -> tuple[Ros2BridgeNode, Bus]:
    clock = WallClock()
    bus = Bus(clock)
    ctx = NodeContext(bus, clock, load_profile(None))
    ctx.resources[ROS2_BRIDGE_SETTINGS] = Ros2BridgeSettings(
        domain_id=DOMAIN, connect=connect, listen=listen, deadman_s=0.3
    )
    return Ros2BridgeNode(ctx), bus


@pytest.fixture
async def bridge():
    port = free_port()
    node, bus = make_bridge((), (f"tcp/127.0.0.1:{port}",))
    await node.setup()
    ros = await asyncio.to_thread(
        zenoh.open, zenoh_config("peer", connect=f"tcp/127.0.0.1:{port}")
    )  # the "ROS 2 node"
    try:
        yield node, bus, ros
    finally:
        await asyncio.to_thread(ros.close)
        await node.teardown()
        await node._close()


async def test_scan_arrives_as_cdr_on_the_rmw_zenoh_key(bridge):
    _node, bus, ros = bridge
    got: list[zenoh.Sample] = []
    sub = ros.declare_subscriber(key("/scan", "sensor_msgs/LaserScan"), got.append)
    ranges = np.linspace(0.5, 4.0, 360).astype(np.float32)
    scan = LaserScan(100.5, "laser", -math.pi, math.tau / 360, 0.15, 12.0, ranges)

    async def resend():
        while True:
            bus.publish(topics.SCAN, scan)
            await asyncio.sleep(RESEND_S)

    task = asyncio.create_task(resend())
    try:
        await until(lambda: got, "a /scan sample on the rmw_zenoh key")
    finally:
        task.cancel()
        sub.undeclare()
    sample = got[0]
    assert sample.payload.to_bytes() == ros2_cdr.encode("sensor_msgs/LaserScan", ros2.laser_scan(scan))
    back = ros2_cdr.decode("sensor_msgs/LaserScan", sample.payload.to_bytes())
    assert np.array_equal(np.asarray(back["ranges"], np.float32), ranges)
    assert back["header"]["frame_id"] == "laser"
    assert sample.attachment is not None
    att = Attachment.decode(sample.attachment.to_bytes())
    assert att.sequence_number >= 1
    assert len(att.source_gid) == 16


async def test_map_reaches_a_late_transient_local_subscriber(bridge, shared_data):
    """/map is published once, before the ROS node subscribes: an rmw_zenoh transient-local
    subscription (an advanced subscriber asking for history) still gets it from the cache."""
    node, bus, ros = bridge
    grid = read_map(shared_data("maps/tb3-sandbox/tb3_sandbox.yaml"))
    bus.declare(topics.MAP, OccupancyGrid, latched=True)
    bus.publish(topics.MAP, grid)
    await until(lambda: node.counts["sent"] > 0, "the map sent by the bridge")
    got: list[zenoh.Sample] = []
    history = zenoh.ext.HistoryConfig(detect_late_publishers=True, max_samples=1)
    sub = zenoh.ext.declare_advanced_subscriber(
        ros, key("/map", "nav_msgs/OccupancyGrid"), got.append, history=history
    )
    try:
        await until(lambda: got, "the cached /map")
    finally:
        sub.undeclare()
    back = ros2_cdr.decode("nav_msgs/OccupancyGrid", got[0].payload.to_bytes())
    assert (back["info"]["width"], back["info"]["height"]) == (grid.width, grid.height)
    assert np.array_equal(np.asarray(back["data"], np.int8).reshape(grid.data.shape), grid.data)

    # /tf_static (sent once at start) reaches a late joiner the same way: the lidar mount.
    statics: list[zenoh.Sample] = []
    sub = zenoh.ext.declare_advanced_subscriber(
        ros, key("/tf_static", "tf2_msgs/TFMessage"), statics.append, history=history
    )
    try:
        await until(lambda: statics, "the cached /tf_static")
    finally:
        sub.undeclare()
    tfs = ros2_cdr.decode("tf2_msgs/TFMessage", statics[0].payload.to_bytes())["transforms"]
    laser = next(t for t in tfs if t["child_frame_id"] == "laser")
    mount = node.settings.robot.lidar
    assert laser["header"]["frame_id"] == "base_link"
    assert laser["transform"]["translation"] == pytest.approx(
        {"x": mount.x_m, "y": mount.y_m, "z": mount.z_m}
    )
    assert {t["child_frame_id"] for t in tfs} == {"laser", "imu_link"}


async def test_graph_tokens_announce_the_node_and_its_topics(bridge):
    node, _bus, ros = bridge

    def tokens() -> set[str]:
        return {
            str(r.ok.key_expr) for r in ros.liveliness().get(f"@ros2_lv/{DOMAIN}/**", timeout=2.0) if r.ok
        }

    want = set(node.tokens)
    seen: set[str] = set()
    for _ in range(MAX_TRIES):  # bounded: the tokens propagate within a few round trips
        seen = await asyncio.to_thread(tokens)
        if seen >= want:
            break
    assert seen >= want, f"missing tokens: {sorted(want - seen)}"
    kinds = {t.split("/")[5] for t in seen}
    assert kinds == {"NN", "MP", "MS"}
    pub_topics = {t.split("/")[9] for t in seen if "/MP/" in t}
    assert {
        "%scan",
        "%odom",
        "%tf",
        "%map",
        "%imu%data",
        "%battery_state",
        "%amcl_pose",
        "%plan",
    } <= pub_topics
    map_token = next(t for t in seen if "/%map/" in t)
    assert map_token.endswith("/:1:,1:,:,:,,")  # reliable, transient local, depth 1
    assert any(
        t.endswith(
            "/MS/%/%/sage/%cmd_vel/geometry_msgs::msg::dds_::Twist_/"
            + ros2_cdr.type_hash("geometry_msgs/Twist")
            + "/::,10:,:,:,,"
        )
        for t in seen
    )


def twist_cdr(v: float, w: float) -> bytes:  # encoded by the other serializer, as a ROS node would send it
    enc = serialize_dynamic("geometry_msgs/Twist", ros2.msgdef("geometry_msgs/Twist"))["geometry_msgs/Twist"]
    return enc(ros2.twist(Twist(v, w)))


async def test_cmd_vel_from_ros_drives_with_clamp_deadman_and_estop(bridge):
    node, bus, ros = bridge
    seen: list[Twist] = []
    bus.subscribe(topics.CMD_VEL, Twist, seen.append)
    pub = ros.declare_publisher(key("/cmd_vel", "geometry_msgs/Twist"))
    gid = bytes(16)
    max_v = node.settings.robot.max_linear_mps

    async def send_until(v: float, w: float, cond: Callable[[], bool], what: str) -> None:
        for seq in range(1, MAX_TRIES + 1):  # re-send until the subscription has propagated
            pub.put(twist_cdr(v, w), attachment=Attachment(seq, 0, gid).encode())
            await asyncio.sleep(RESEND_S)
            if cond():
                return
        raise AssertionError(f"timed out waiting for {what}")

    await send_until(0.2, 0.1, lambda: Twist(0.2, 0.1) in seen, "the ROS /cmd_vel on SAGE's bus")
    await send_until(5.0, 0.0, lambda: Twist(max_v, 0.0) in seen, "a clamped /cmd_vel")
    # Silence: the deadman stops the robot.
    await until(lambda: seen[-1] == Twist(0.0, 0.0), "the deadman's zero Twist")
    assert node.counts["deadman_stops"] >= 1
    # The e-stop refuses ROS commands: a zero Twist goes out instead.
    bus.declare(topics.ESTOP, EStopState, latched=True)
    bus.publish(topics.ESTOP, EStopState(True, "operator"))
    seen.clear()
    await send_until(0.3, 0.0, lambda: node.counts["refused"] > 0, "a refused /cmd_vel")
    assert Twist(0.3, 0.0) not in seen
    assert seen[-1] == Twist(0.0, 0.0)
    # Garbage is counted, never raised.
    pub.put(b"\x00\x01\x00\x00garbage")
    await until(lambda: node.counts["bad_samples"] > 0, "the bad sample counted")
    pub.undeclare()


async def test_goal_pose_from_ros_becomes_a_navigation_goal(bridge):
    node, bus, ros = bridge
    goals = []
    shown: list[PoseStamped] = []
    bus.subscribe(topics.GOAL_POSE, PoseStamped, shown.append)  # what the web map draws

    async def navigate(goal, ctx):
        goals.append(goal)

    pub = ros.declare_publisher(key("/goal_pose", "geometry_msgs/PoseStamped"))
    enc = serialize_dynamic("geometry_msgs/PoseStamped", ros2.msgdef("geometry_msgs/PoseStamped"))
    wrong_frame = enc["geometry_msgs/PoseStamped"](
        ros2.pose_stamped(PoseStamped(1.0, "odom", Pose2D(1, 1, 0)))
    )
    good = enc["geometry_msgs/PoseStamped"](
        ros2.pose_stamped(PoseStamped(1.0, "map", Pose2D(2.0, -1.0, 1.5)))
    )

    async def resend(payload: bytes):
        while True:
            pub.put(payload)
            await asyncio.sleep(RESEND_S)

    # No navigator yet: refused, not crashed. A goal in another frame: a bad sample.
    task = asyncio.create_task(resend(good))
    await until(lambda: node.counts["refused"] > 0, "a /goal_pose refused without a navigator")
    task.cancel()
    pub.put(wrong_frame)
    await until(lambda: node.counts["bad_samples"] > 0, "the odom-frame goal rejected")
    bus.actions.serve(topics.NAVIGATE_TO, navigate)
    task = asyncio.create_task(resend(good))
    try:
        await until(lambda: goals, "a navigate_to goal from /goal_pose")
    finally:
        task.cancel()
        pub.undeclare()
    pose = goals[0].pose
    assert (pose.x, pose.y, pose.theta) == pytest.approx((2.0, -1.0, 1.5))
    assert shown
    assert shown[0].frame_id == "map"
    assert shown[0].pose == pose
    assert not any(g.pose.x == 1 for g in goals)


def test_settings_from_the_environment():
    s = Ros2BridgeSettings.from_env(
        {"ROS_DOMAIN_ID": "7", "SAGE_ROS2_CONNECT": "tcp/10.0.0.2:7447, tcp/10.0.0.3:7447"}
    )
    assert (s.domain_id, s.connect, s.listen) == (
        7,
        ("tcp/10.0.0.2:7447", "tcp/10.0.0.3:7447"),
        ("tcp/localhost:0",),
    )
    assert Ros2BridgeSettings.from_env({}).connect == ("tcp/localhost:7447",)
    with pytest.raises(ConfigError, match=r"ROS_DOMAIN_ID must be an integer 0\.\.232, got 'x'"):
        Ros2BridgeSettings.from_env({"ROS_DOMAIN_ID": "x"})
    with pytest.raises(ConfigError, match="SAGE_ROS2_LISTEN: 'localhost:7447' is not a Zenoh endpoint"):
        Ros2BridgeSettings.from_env({"SAGE_ROS2_LISTEN": "localhost:7447"})
    assert Ros2BridgeSettings.from_env({"SAGE_ROS2_CONNECT": ""}).connect == ()


def test_cli_flag_adds_the_bridge_and_checks_its_environment(monkeypatch):
    from sage_robot.cli.run import ros2_specs

    monkeypatch.setenv("ROS_DOMAIN_ID", "12")
    (spec,) = ros2_specs("sim")
    assert (spec.name, spec.factory, spec.critical) == ("ros2_bridge", Ros2BridgeNode, False)
    monkeypatch.setenv("ROS_DOMAIN_ID", "999")
    with pytest.raises(ConfigError, match="ROS_DOMAIN_ID must be an integer"):
        ros2_specs("tour")


async def test_through_a_router_as_rmw_zenoh_deploys():
    """rmw_zenoh's shape: a router (rmw_zenohd's role, here a Zenoh session in router mode), the
    bridge and a ROS node both peers of it. The ROS node's graph cache (a liveliness subscriber
    with history, as rmw_zenoh declares it) learns every token, and /scan flows."""
    router_end = f"tcp/127.0.0.1:{free_port()}"
    router = await asyncio.to_thread(zenoh.open, zenoh_config("router", listen=router_end))
    node, bus = make_bridge((router_end,), ("tcp/127.0.0.1:0",))
    await node.setup()
    ros = await asyncio.to_thread(
        zenoh.open, zenoh_config("peer", connect=router_end, listen="tcp/127.0.0.1:0")
    )
    try:
        graph: list[zenoh.Sample] = []
        ros.liveliness().declare_subscriber(f"@ros2_lv/{DOMAIN}/**", graph.append, history=True)
        got: list[zenoh.Sample] = []
        ros.declare_subscriber(key("/scan", "sensor_msgs/LaserScan"), got.append)
        scan = LaserScan(1.0, "laser", -math.pi, math.tau / 360, 0.15, 12.0, np.ones(360, np.float32))
        for _ in range(MAX_TRIES):
            bus.publish(topics.SCAN, scan)
            await asyncio.sleep(RESEND_S)
            if got and len(graph) >= len(node.tokens):
                break
        assert got, "no /scan through the router"
        assert {str(s.key_expr) for s in graph} == set(node.tokens)
    finally:
        await asyncio.to_thread(ros.close)
        await node.teardown()
        await node._close()
        await asyncio.to_thread(router.close)
