"""ROS 2 bridge: SAGE's topics as ROS 2 CDR under rmw_zenoh's key expressions (off by default).

A ROS 2 node that uses ``rmw_zenoh_cpp`` (Jazzy, Kilted) on the same Zenoh network sees a node
``/sage`` publishing ``/scan``, ``/odom``, ``/tf``, ``/tf_static``, ``/map``, ``/imu/data``,
``/battery_state``, ``/amcl_pose`` and ``/plan``, and subscribing ``/cmd_vel`` and
``/goal_pose``: samples are CDR (:mod:`.ros2_cdr`) on the data keys, with rmw_zenoh's attachment,
and the graph is announced with its liveliness tokens (:mod:`.rmw_zenoh`). The field mappings
are those of the MCAP recorder (:mod:`.recording.ros2`).

- **Out**: one task per output waits for the latest message (a one-slot queue: the newest wins)
  and sends it, then rests ``min_period_s`` (rate limits for the heavy topics). Conversion and
  encoding run through ``clock.offload``; ``/map`` is transient-local (late joiners get the
  last one from the publisher's cache, as from a ROS map server).
- **In**, with the web teleop's safety rules: ``/cmd_vel`` is clamped to the robot's limits,
  refused (a zero Twist is sent instead) while the e-stop is engaged, and a *deadman* publishes
  a zero Twist when no command came for ``deadman_s`` after a non-zero one (wall time, like the
  teleop's, since the ROS peer lives in real seconds; the serial bridge's command timeout is
  the next layer). ``/goal_pose`` (frame ``map``) becomes a ``navigate_to`` goal, refused while
  the e-stop is engaged. Malformed samples are counted and logged once per kind, never raised.

Settings come from the environment at start (``ROS_DOMAIN_ID`` as in ROS 2,
``SAGE_ROS2_CONNECT``/``SAGE_ROS2_LISTEN`` endpoint lists) or from ``ROS2_BRIDGE_SETTINGS``.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import os
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import zenoh
import zenoh.ext

from sage_robot.app import ros2_cdr
from sage_robot.app.recording import ros2
from sage_robot.app.rmw_zenoh import (
    Attachment,
    Durability,
    Entity,
    NodeInfo,
    Qos,
    Reliability,
    entity_gid,
    liveliness_token,
    topic_keyexpr,
)
from sage_robot.core import topics
from sage_robot.core.bus import Subscription, Topic
from sage_robot.core.config import Settings
from sage_robot.core.errors import ConfigError
from sage_robot.core.msgs import OccupancyGrid, Pose2D, PoseStamped, Twist
from sage_robot.core.msgs.nav import NavigateGoal
from sage_robot.core.node import Node, NodeContext
from sage_robot.core.resources import ResourceKey

ROUTER_ENDPOINT = (
    "tcp/localhost:7447"  # where rmw_zenoh's router (`ros2 run rmw_zenoh_cpp rmw_zenohd`) listens
)
LOCAL_LISTEN_ENDPOINT = "tcp/localhost:0"  # rmw_zenoh's default: any free port, this host only
DEADMAN_S = 0.5  # zero /cmd_vel after this silence (s); teleop_twist_joy repeats at 20 Hz
DEADMAN_CHECK_S = 0.02  # how often the deadman looks (s)
SAMPLE_MISS_HEARTBEAT_S = 0.5  # rmw_zenoh's heartbeat of reliable transient-local publishers (s)
GOAL_SEND_TIMEOUT_S = 2.0  # bound on handing a /goal_pose to the navigator (s)
SEQUENCE_START = 1  # rmw_zenoh numbers each publisher's samples from 1
NS_PER_S = 1_000_000_000
SCAN_MIN_PERIOD_S = 0.1  # /scan at most 10 Hz
ODOM_MIN_PERIOD_S = 0.05  # /odom and odom -> base_link at most 20 Hz
MAP_MIN_PERIOD_S = 2.0  # /map at most every 2 s (SLAM grows it several times a second)
PLAN_MIN_PERIOD_S = 0.5  # /plan at most 2 Hz
BATTERY_MIN_PERIOD_S = 1.0  # /battery_state at most 1 Hz (the MCU reports it with every status frame)

MAX_DOMAIN_ID = 232  # the largest ROS_DOMAIN_ID ROS 2 allows

SENSOR_QOS = Qos(Reliability.BEST_EFFORT, Durability.VOLATILE, depth=5)  # rclcpp SensorDataQoS
DEFAULT_QOS = Qos(Reliability.RELIABLE, Durability.VOLATILE, depth=10)
TF_QOS = Qos(Reliability.RELIABLE, Durability.VOLATILE, depth=100)  # tf2_ros's TransformBroadcaster
LATCHED_QOS = Qos(Reliability.RELIABLE, Durability.TRANSIENT_LOCAL, depth=1)  # map_server's /map


@dataclass(frozen=True)
class Ros2BridgeSettings:
    """Where the bridge joins the ROS 2 network and under which names."""

    domain_id: int = 0  # ROS_DOMAIN_ID: the first chunk of every key
    connect: tuple[str, ...] = (ROUTER_ENDPOINT,)  # Zenoh endpoints to connect to
    listen: tuple[str, ...] = (LOCAL_LISTEN_ENDPOINT,)  # Zenoh endpoints to listen on (peers connect here)
    node_name: str = "sage"
    namespace: str = "/"
    deadman_s: float = DEADMAN_S

    @classmethod
    def from_env(cls, env: Mapping[str, str]) -> Ros2BridgeSettings:
        raw = env.get("ROS_DOMAIN_ID", "0").strip() or "0"
        if not raw.isdigit() or int(raw) > MAX_DOMAIN_ID:
            raise ConfigError(f"ROS_DOMAIN_ID must be an integer 0..{MAX_DOMAIN_ID}, got {raw!r}")

        def endpoints(name: str, default: tuple[str, ...]) -> tuple[str, ...]:
            value = env.get(name)
            found = default if value is None else tuple(e.strip() for e in value.split(",") if e.strip())
            for e in found:
                proto, _, address = e.partition("/")
                if not proto or not address or any(c in e for c in '"[] '):
                    raise ConfigError(f"{name}: {e!r} is not a Zenoh endpoint (e.g. tcp/192.168.1.5:7447)")
            return found

        return cls(
            int(raw),
            endpoints("SAGE_ROS2_CONNECT", (ROUTER_ENDPOINT,)),
            endpoints("SAGE_ROS2_LISTEN", (LOCAL_LISTEN_ENDPOINT,)),
        )


ROS2_BRIDGE_SETTINGS: ResourceKey[Ros2BridgeSettings] = ResourceKey(
    "ros2_bridge_settings", Ros2BridgeSettings, doc="overrides the environment (tests, embedding)"
)


@dataclass(frozen=True)
class Outgoing:
    """One SAGE topic sent to ROS 2."""

    sage: Topic[Any]
    ros_topic: str
    ros_type: str
    convert: Callable[[Any], dict[str, Any]]
    qos: Qos = DEFAULT_QOS
    min_period_s: float = 0.0


def _map_odom_tf(m: PoseStamped) -> dict[str, Any]:
    return ros2.pose_tf(m, "odom")


def _map(m: OccupancyGrid) -> dict[str, Any]:
    return ros2.occupancy_grid(m, as_array=True)


def static_tf(settings: Settings, stamp: float) -> dict[str, Any]:
    """``/tf_static``: base_link -> laser (the profile's lidar mount) and base_link -> imu_link."""
    lidar = settings.robot.lidar
    laser = ros2.pose_tf(
        PoseStamped(stamp, "base_link", Pose2D(lidar.x_m, lidar.y_m, lidar.yaw_rad)), "laser"
    )
    laser["transforms"][0]["transform"]["translation"]["z"] = lidar.z_m  # the scan plane's height
    imu = ros2.pose_tf(PoseStamped(stamp, "base_link", Pose2D()), "imu_link")
    return {"transforms": laser["transforms"] + imu["transforms"]}


OUTGOING: tuple[Outgoing, ...] = (
    Outgoing(topics.SCAN, "/scan", "sensor_msgs/LaserScan", ros2.laser_scan, SENSOR_QOS, SCAN_MIN_PERIOD_S),
    Outgoing(topics.ODOM, "/odom", "nav_msgs/Odometry", ros2.odometry, DEFAULT_QOS, ODOM_MIN_PERIOD_S),
    Outgoing(topics.ODOM, "/tf", "tf2_msgs/TFMessage", ros2.odom_tf, TF_QOS, ODOM_MIN_PERIOD_S),
    Outgoing(topics.MAP_ODOM, "/tf", "tf2_msgs/TFMessage", _map_odom_tf, TF_QOS),
    Outgoing(topics.MAP, "/map", "nav_msgs/OccupancyGrid", _map, LATCHED_QOS, MAP_MIN_PERIOD_S),
    Outgoing(topics.IMU, "/imu/data", "sensor_msgs/Imu", ros2.imu, SENSOR_QOS),
    Outgoing(
        topics.BATTERY,
        "/battery_state",
        "sensor_msgs/BatteryState",
        ros2.battery,
        DEFAULT_QOS,
        BATTERY_MIN_PERIOD_S,
    ),
    Outgoing(
        topics.AMCL_POSE, "/amcl_pose", "geometry_msgs/PoseWithCovarianceStamped", ros2.pose_with_covariance
    ),
    Outgoing(topics.PLAN, "/plan", "nav_msgs/Path", ros2.path, DEFAULT_QOS, PLAN_MIN_PERIOD_S),
)
TF_STATIC, TF_TYPE = "/tf_static", "tf2_msgs/TFMessage"  # latched, as tf2's StaticTransformBroadcaster
INCOMING: dict[str, str] = {"/cmd_vel": "geometry_msgs/Twist", "/goal_pose": "geometry_msgs/PoseStamped"}


def _encode(out: Outgoing, msg: Any) -> bytes:
    return ros2_cdr.encode(out.ros_type, out.convert(msg))


@dataclass
class _Publisher:
    handle: Any  # zenoh.Publisher or zenoh.ext.AdvancedPublisher
    gid: bytes
    sequence: int = SEQUENCE_START


class Ros2BridgeNode(Node):
    name = "ros2_bridge"

    def __init__(self, ctx: NodeContext) -> None:
        super().__init__(ctx)
        self.config = ctx.resources.get(ROS2_BRIDGE_SETTINGS) or Ros2BridgeSettings.from_env(os.environ)
        self.session: zenoh.Session | None = None
        self._publishers: dict[str, _Publisher] = {}
        self._declared: list[Any] = []  # liveliness tokens and subscribers, undeclared at teardown
        self.tokens: list[str] = []  # the liveliness key expressions (what `ros2 node info` is built from)
        self.command = (0.0, 0.0)
        self.last_command = 0.0  # time.monotonic() of the last /cmd_vel
        self.counts = {
            "sent": 0,
            "cmd_vel": 0,
            "goals": 0,
            "refused": 0,
            "bad_samples": 0,
            "deadman_stops": 0,
        }
        self._warned: set[str] = set()
        robot = self.settings.robot
        self.max_v, self.max_w = robot.max_linear_mps, robot.max_angular_radps

    def stats(self) -> dict[str, Any]:
        return dict(self.counts)

    # ------------------------------------------------------------ lifecycle
    async def setup(self) -> None:
        c = self.config
        config = zenoh.Config()
        config.insert_json5("mode", '"peer"')
        config.insert_json5("connect/endpoints", _json_list(c.connect))
        config.insert_json5("listen/endpoints", _json_list(c.listen))
        config.insert_json5("scouting/multicast/enabled", "false")  # rmw_zenoh's default: a router
        config.insert_json5("timestamping/enabled", "true")  # the advanced publisher's cache needs it
        self.session = await self.clock.offload(zenoh.open, config)
        node = NodeInfo(c.domain_id, str(self.session.info.zid()), 0, c.node_name, c.namespace)
        self._token(liveliness_token(node, 0, Entity.NODE))
        ids = itertools.count(1)  # entity ids of the node's publishers and subscriptions
        for out in OUTGOING:
            if out.ros_topic not in self._publishers:
                self._declare_publisher(node, next(ids), out.ros_topic, out.ros_type, out.qos)
            sub = self.subscribe(out.sage, out.sage.msg_type, maxsize=1)  # the newest message wins
            self.spawn(self._pump(out, sub), f"ros2_bridge.{out.ros_topic}")
        for topic, ros_type in INCOMING.items():
            self._declare_subscriber(node, next(ids), topic, ros_type)
        self._declare_publisher(node, next(ids), TF_STATIC, TF_TYPE, LATCHED_QOS)
        static = await self.clock.offload(
            ros2_cdr.encode, TF_TYPE, static_tf(self.settings, self.clock.now())
        )
        self._put(TF_STATIC, static)  # once: late joiners get it from the publisher's cache
        self.spawn(self._deadman_loop(), "ros2_bridge.deadman")
        self.log.info("ROS 2 bridge up", domain=c.domain_id, zid=node.zid, connect=list(c.connect))

    async def teardown(self) -> None:
        if self.command != (0.0, 0.0):
            self._drive(0.0, 0.0)
        for entity in reversed(self._declared):
            with contextlib.suppress(Exception):
                entity.undeclare()
        self._declared.clear()
        for pub in self._publishers.values():
            with contextlib.suppress(Exception):
                pub.handle.undeclare()
        self._publishers.clear()
        if self.session is not None:
            session, self.session = self.session, None
            await self.clock.offload(session.close)

    # ------------------------------------------------------------ declarations
    def _token(self, key: str) -> None:
        assert self.session is not None
        self._declared.append(self.session.liveliness().declare_token(key))
        self.tokens.append(key)

    def _declare_publisher(
        self, node: NodeInfo, entity_id: int, ros_topic: str, ros_type: str, qos: Qos
    ) -> None:
        assert self.session is not None
        dds, type_hash = ros2_cdr.dds_type_name(ros_type), ros2_cdr.type_hash(ros_type)
        key = topic_keyexpr(node.domain_id, ros_topic, dds, type_hash)
        reliability = (
            zenoh.Reliability.RELIABLE
            if qos.reliability == Reliability.RELIABLE
            else zenoh.Reliability.BEST_EFFORT
        )
        options: dict[str, Any] = {
            "reliability": reliability,
            "congestion_control": zenoh.CongestionControl.DROP,
        }
        if qos.durability == Durability.TRANSIENT_LOCAL:  # as rmw_zenoh: a cache late joiners query
            options.update(cache=zenoh.ext.CacheConfig(max_samples=qos.depth), publisher_detection=True)
            if qos.reliability == Reliability.RELIABLE:  # subscribers detect and recover a lost sample
                options["sample_miss_detection"] = zenoh.ext.MissDetectionConfig(
                    heartbeat=None, sporadic_heartbeat=SAMPLE_MISS_HEARTBEAT_S
                )
        handle = zenoh.ext.declare_advanced_publisher(self.session, key, **options)
        token = liveliness_token(node, entity_id, Entity.PUBLISHER, ros_topic, dds, type_hash, qos)
        self._publishers[ros_topic] = _Publisher(handle, entity_gid(token))
        self._token(token)

    def _declare_subscriber(self, node: NodeInfo, entity_id: int, topic: str, ros_type: str) -> None:
        assert self.session is not None
        dds, type_hash = ros2_cdr.dds_type_name(ros_type), ros2_cdr.type_hash(ros_type)
        # Any hash: a Humble peer sends "TypeHashNotSupported" there; the type name still binds.
        key = topic_keyexpr(node.domain_id, topic, dds, "*")
        loop = asyncio.get_running_loop()

        def on_sample(sample: zenoh.Sample) -> None:  # a Zenoh thread: hand the bytes to the loop
            data = sample.payload.to_bytes()
            with contextlib.suppress(RuntimeError):  # the loop closed: shutting down
                loop.call_soon_threadsafe(self._incoming, topic, data)

        self._declared.append(self.session.declare_subscriber(key, on_sample))
        self._token(
            liveliness_token(node, entity_id, Entity.SUBSCRIPTION, topic, dds, type_hash, DEFAULT_QOS)
        )

    # ------------------------------------------------------------ out
    async def _pump(self, out: Outgoing, sub: Subscription[Any]) -> None:
        while True:
            msg = await sub.get()
            payload = await self.clock.offload(_encode, out, msg)
            self._put(out.ros_topic, payload)
            if out.min_period_s > 0:
                await self.clock.sleep(out.min_period_s)

    def _put(self, ros_topic: str, payload: bytes) -> None:
        pub = self._publishers[ros_topic]
        stamp_ns = round(self.clock.now() * NS_PER_S)
        attachment = Attachment(pub.sequence, stamp_ns, pub.gid).encode()
        pub.sequence += 1
        pub.handle.put(payload, attachment=attachment)
        self.counts["sent"] += 1

    # ------------------------------------------------------------ in
    def _incoming(self, topic: str, data: bytes) -> None:
        try:
            value = ros2_cdr.decode(INCOMING[topic], data)
            if topic == "/cmd_vel":
                self._on_cmd_vel(ros2.twist_from_ros(value))
            else:
                self._on_goal(ros2.pose_stamped_from_ros(value))
        except (ros2_cdr.CdrError, ValueError, KeyError) as exc:
            self.counts["bad_samples"] += 1
            if topic not in self._warned:  # once per topic: a flood of bad samples must not flood the log
                self._warned.add(topic)
                self.log.warning("bad ROS 2 sample ignored", topic=topic, error=str(exc))

    def _estop(self) -> bool:
        state = self.bus.latest(topics.ESTOP)
        return bool(state is not None and state.engaged)

    def _on_cmd_vel(self, cmd: Twist) -> None:
        self.counts["cmd_vel"] += 1
        if self._estop():
            self.counts["refused"] += 1
            self._drive(0.0, 0.0)
            return
        self.last_command = time.monotonic()
        v = max(-self.max_v, min(self.max_v, cmd.linear_x))
        w = max(-self.max_w, min(self.max_w, cmd.angular_z))
        self._drive(v, w)

    def _drive(self, v: float, w: float) -> None:
        self.command = (v, w)
        self.bus.publish(topics.CMD_VEL, Twist(v, w))

    def _on_goal(self, goal: PoseStamped) -> None:
        if goal.frame_id not in ("map", "/map"):
            raise ValueError(f"/goal_pose must be in the map frame, got {goal.frame_id!r}")
        if self._estop() or not self.bus.actions.has(topics.NAVIGATE_TO):
            self.counts["refused"] += 1
            self.log.warning(
                "/goal_pose refused", estop=self._estop(), navigator=self.bus.actions.has(topics.NAVIGATE_TO)
            )
            return
        self.counts["goals"] += 1
        self.bus.publish(topics.GOAL_POSE, PoseStamped(self.clock.now(), "map", goal.pose))
        self.spawn(self._send_goal(goal), "ros2_bridge.goal")

    async def _send_goal(self, goal: PoseStamped) -> None:
        send = self.bus.actions.send_goal(topics.NAVIGATE_TO, NavigateGoal(pose=goal.pose))
        try:
            await self.clock.wait_for(send, GOAL_SEND_TIMEOUT_S)
        except Exception as exc:  # a navigator that is busy or gone: the goal is dropped, the bridge goes on
            self.log.warning("/goal_pose not accepted", error=str(exc))

    async def _deadman_loop(self) -> None:
        """Wall time on purpose (see the module doc); every step is synchronous."""
        while True:
            await asyncio.sleep(DEADMAN_CHECK_S)
            silent = time.monotonic() - self.last_command
            if self.command != (0.0, 0.0) and silent > self.config.deadman_s:
                self.counts["deadman_stops"] += 1
                self.log.info("deadman: no /cmd_vel from ROS 2, stopping", silent_s=round(silent, 2))
                self._drive(0.0, 0.0)


def _json_list(items: tuple[str, ...]) -> str:
    return "[" + ",".join(f'"{i}"' for i in items) + "]"
