"""The bus over Zenoh: the wire encoding, and two buses in two processes on loopback.

Each test uses its own robot id (Zenoh key prefix) and free ports with explicit endpoints
(no multicast), so parallel runs do not hear each other.
"""

from __future__ import annotations

import asyncio
import struct
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("zenoh")

from sage_robot.core import topics
from sage_robot.core.bus import Bus
from sage_robot.core.clock import WallClock
from sage_robot.core.config import parse_profile
from sage_robot.core.config.bus import BusSettings, ZenohSettings
from sage_robot.core.errors import ConfigError, SageError, ServiceError, ServiceTimeout, ServiceUnavailable
from sage_robot.core.msgs import BatteryState, LaserScan, Odometry, Pose2D, PowerStatus, Text, Twist
from sage_robot.core.transport import wire
from sage_robot.core.transport.keys import TX_QUEUE_KEY, check_topic, session_config, topic_key, topic_of
from sage_robot.core.transport.remote import RemoteRobot
from sage_robot.core.transport.zenoh_bus import ZenohTransport, repeats
from tests.core.test_msgs import EXAMPLES
from tests.core.zenoh_peer import HEARD, UPPER, free_port, running_peer, unique_robot
from tests.support.waits import until


@pytest.mark.parametrize("msg", EXAMPLES, ids=lambda m: type(m).__name__)
def test_every_message_round_trips_through_the_wire(msg: Any) -> None:
    assert wire.decode(wire.encode(msg)) == msg


def test_arrays_travel_as_raw_buffers_and_come_back_writable() -> None:
    ranges = np.linspace(0.2, 8.0, 360, dtype=np.float32)
    ranges[[0, 7]] = [np.inf, np.nan]
    scan = LaserScan(1.0, "laser", -np.pi, np.pi / 180, 0.15, 12.0, ranges)
    frame = wire.encode(scan)
    assert ranges.tobytes() in frame  # not a JSON list of 360 numbers
    assert len(frame) < ranges.nbytes + 400
    back = wire.decode(frame, LaserScan)
    assert back == scan
    assert back.ranges.flags.writeable


def _frame(head: bytes, body: bytes = b"") -> bytes:
    return struct.pack("<2sBI", b"SG", 1, len(head)) + head + body


@pytest.mark.parametrize(
    ("frame", "why"),
    [
        (b"SG", "too short"),
        (b"XX\x01\x00\x00\x00\x00", "not a SAGE frame"),
        (_frame(b"{}"), "no buffer table"),
        (_frame(b'{"type":"Twist","__buffers__":[5]}', b"abc"), "5 bytes announced"),
        (_frame(b'{"type":"Pickle","__buffers__":[]}'), "unknown message type"),
        (_frame(b'{"type":"Twist","linear_x":"fast","__buffers__":[]}'), "Twist.linear_x"),
        (_frame(b'{"type":"Text","__buffers__":[]}'), "missing field"),
        (_frame(b"[1,2", b""), "bad header"),
        (
            _frame(
                b'{"type":"LaserScan","stamp":0,"frame_id":"l","angle_min":0,"angle_increment":1,'
                b'"range_min":0,"range_max":1,"ranges":{"__nd__":0,"dtype":"|O","shape":[1]},'
                b'"__buffers__":[8]}',
                b"\x00" * 8,
            ),
            "not accepted",
        ),
        (
            _frame(
                b'{"type":"LaserScan","stamp":0,"frame_id":"l","angle_min":0,"angle_increment":1,'
                b'"range_min":0,"range_max":1,"ranges":{"__nd__":0,"dtype":"<f4","shape":[3]},'
                b'"__buffers__":[8]}',
                b"\x00" * 8,
            ),
            "does not match",
        ),
    ],
)
def test_bad_frames_are_refused_with_a_reason(frame: bytes, why: str) -> None:
    with pytest.raises(wire.WireError, match=why):
        wire.decode(frame)


def test_unregistered_objects_do_not_go_on_the_wire() -> None:
    with pytest.raises(TypeError, match="not a registered message"):
        wire.encode(object())


def test_key_expressions_and_topic_names() -> None:
    assert topic_key("r1", "/imu/data") == "sage/r1/topic/imu/data"
    assert topic_of("r1", "topic", "sage/r1/topic/imu/data") == "/imu/data"
    assert topic_of("r1", "topic", "sage/r2/topic/imu/data") is None
    for bad in ("cmd_vel", "/a/*", "/a//b", "/", "/a b", "/**"):
        with pytest.raises(SageError, match="bad topic name"):
            check_topic(bad)


def test_the_profile_selects_and_checks_the_transport() -> None:
    assert parse_profile("").bus.transport == "local"
    s = parse_profile(
        "bus:\n  transport: zenoh\n  robot_id: lab_2\n  zenoh:\n    listen: [tcp/127.0.0.1:7500]\n"
    )
    assert (s.bus.transport, s.bus.robot_id) == ("zenoh", "lab_2")
    assert s.bus.zenoh.listen == ("tcp/127.0.0.1:7500",)
    with pytest.raises(ConfigError, match=r"bus.robot_id \(line 2\)"):
        parse_profile("bus:\n  robot_id: a/*\n")
    with pytest.raises(ConfigError, match=r"bus\.transport"):
        parse_profile("bus:\n  transport: carrier-pigeon\n")


def _settings(robot: str, listen: list[str], connect: list[str]) -> BusSettings:
    return BusSettings(
        transport="zenoh", robot_id=robot, zenoh=ZenohSettings(listen=tuple(listen), connect=tuple(connect))
    )


@pytest.fixture
def peer() -> Iterator[tuple[str, int]]:
    robot, port = unique_robot(), free_port()
    with running_peer(robot, port):
        yield robot, port


async def test_two_processes_exchange_typed_messages(peer: tuple[str, int]) -> None:
    robot, port = peer
    transport = ZenohTransport(_settings(robot, [f"tcp/127.0.0.1:{free_port()}"], [f"tcp/127.0.0.1:{port}"]))
    bus = Bus(WallClock(), transport)
    try:
        scans = bus.subscribe(topics.SCAN, LaserScan)
        heard = bus.subscribe(HEARD, Text)
        mine = bus.subscribe(topics.CMD_VEL, Twist, maxsize=1000)
        scan = await asyncio.wait_for(scans.get(), 10)
        assert isinstance(scan, LaserScan)
        assert scan.ranges.shape == (360,)
        assert scan.ranges.dtype == np.float32
        assert np.isinf(scan.ranges[0])
        sent = 0

        def answered() -> bool:
            nonlocal sent
            if heard.pending():
                return True
            bus.publish(topics.CMD_VEL, Twist(0.25, 0.0))  # until the peer's subscription matched
            sent += 1
            return False

        await until(answered, "the peer answered a /cmd_vel", poll=0.05)
        assert heard.get_nowait() == Text("0.25")
        await asyncio.sleep(0.2)  # time for an echo of our own publications to come back, if any did
        assert mine.received == sent  # each publication delivered here once: none came back
        assert transport.rejected == 0
        assert bus.remote_rejected == 0
    finally:
        transport.close()


async def test_a_remote_message_of_the_wrong_type_or_no_frame_is_dropped(peer: tuple[str, int]) -> None:
    robot, port = peer
    # Peers do not route for each other: this bus listens so that the tool (told of it by the
    # peer's gossip) can reach it.
    transport = ZenohTransport(_settings(robot, [f"tcp/127.0.0.1:{free_port()}"], [f"tcp/127.0.0.1:{port}"]))
    bus = Bus(WallClock(), transport)
    try:
        twists = bus.subscribe("/peer/heard", Twist)  # the peer publishes Text there
        with RemoteRobot(_settings(robot, [], []), [f"tcp/127.0.0.1:{port}"]) as tool:
            tool.require_connected()
            put = tool.publisher("/peer/heard")

            def refused() -> int:
                put.put(Text("not a twist"))  # again until this bus's subscription is matched
                return bus.remote_rejected

            await until(refused, "the bus refused the Text", poll=0.05)

            def junk_refused() -> int:
                tool.session.put(topic_key(robot, "/peer/heard"), b"\x80\x04junk")  # e.g. a pickle
                return transport.rejected

            await until(junk_refused, "the transport refused a frame that is not one", poll=0.05)
        assert twists.pending() == 0
    finally:
        transport.close()


def test_a_tool_finds_no_robot_within_its_timeout() -> None:
    nobody = [f"tcp/127.0.0.1:{free_port()}"]
    with (
        RemoteRobot(_settings(unique_robot(), [], []), nobody, timeout_s=0.3) as tool,
        pytest.raises(SageError, match="no robot answers"),
    ):
        tool.require_connected()


def test_a_busy_listen_port_is_a_one_line_error(peer: tuple[str, int]) -> None:
    _, port = peer
    with pytest.raises(SageError, match="cannot open the Zenoh session") as err:
        ZenohTransport(_settings(unique_robot(), [f"tcp/127.0.0.1:{port}"], []))
    assert "\n" not in str(err.value)


def test_a_zenoh_config_file_rules_where_the_profile_is_silent(tmp_path: Path) -> None:
    conf = tmp_path / "zenoh.json5"
    conf.write_text(
        '{ mode: "client", connect: { endpoints: ["tls/router.lab:7447"] },\n'
        '  transport: { auth: { usrpwd: { user: "robot", password: "pw" } } } }\n'
    )
    cfg = session_config(ZenohSettings(config_file=str(conf)), None, None)
    assert cfg.get_json("mode") == '"client"'
    assert cfg.get_json("connect/endpoints") == '["tls/router.lab:7447"]'
    assert cfg.get_json("transport/auth/usrpwd/user") == '"robot"'
    cfg = session_config(ZenohSettings(config_file=str(conf), connect=("tcp/10.0.0.2:7450",)), None, None)
    assert cfg.get_json("connect/endpoints") == '["tcp/10.0.0.2:7450"]'
    with pytest.raises(ConfigError, match="not found"):
        session_config(ZenohSettings(config_file=str(tmp_path / "none.json5")), None, None)


def test_zenohs_shared_memory_is_off_unless_the_profile_turns_it_on() -> None:
    """SAGE's messages are plain bytes: the shared-memory transport only added its watchdog
    thread to every process (docs/benchmarks.md, the robot at rest)."""
    assert session_config(ZenohSettings(), None, None).get_json("transport/shared_memory/enabled") == "false"
    on = session_config(ZenohSettings(shared_memory=True), None, None)
    assert on.get_json("transport/shared_memory/enabled") == "true"


def test_a_link_queues_sixteen_messages_before_zenoh_drops_one(tmp_path: Path) -> None:
    """Zenoh's default queue (2 batches, each message its own with express) dropped paced
    /cmd_vel messages between processes on a busy machine (test_bench_zenoh catches it)."""
    assert session_config(ZenohSettings(), None, None).get_json(TX_QUEUE_KEY) == "16"
    assert session_config(ZenohSettings(tx_queue=4), None, None).get_json(TX_QUEUE_KEY) == "4"
    conf = tmp_path / "zenoh.json5"
    conf.write_text("{ transport: { link: { tx: { queue: { size: { data: 8 } } } } } }\n")
    assert session_config(ZenohSettings(config_file=str(conf)), None, None).get_json(TX_QUEUE_KEY) == "8"
    with pytest.raises(ValueError, match="tx_queue"):
        ZenohSettings(tx_queue=17)


async def test_a_service_of_another_process_is_called_through_the_bus(peer: tuple[str, int]) -> None:
    robot, port = peer
    transport = ZenohTransport(_settings(robot, [], [f"tcp/127.0.0.1:{port}"]))
    bus = Bus(WallClock(), transport)
    try:
        reply = await until_value(lambda: bus.call(UPPER, Text("hello"), timeout=2.0))
        assert reply == Text("HELLO")
        await until(lambda: bus.has_service(UPPER), "the peer's service is known here", poll=0.02)
        assert not bus.has_service("/peer/nothing")
        with pytest.raises(ServiceError, match="boom was asked for"):
            await bus.call(UPPER, Text("boom"), timeout=2.0)
        with pytest.raises(ServiceTimeout, match=r"within 0\.3 s"):
            await bus.call(UPPER, Text("slow"), timeout=0.3)
        with pytest.raises(ServiceUnavailable, match="/peer/nothing"):
            await bus.call("/peer/nothing", Text("x"), timeout=2.0)
        assert transport.services.called >= 4
    finally:
        transport.close()


async def until_value(make_call: Any) -> Any:
    """The call's reply, asked again while the peer's queryable is not yet known here."""
    result: list[Any] = []

    async def attempt() -> bool:
        try:
            result.append(await make_call())
        except ServiceUnavailable:
            return False
        return True

    for _ in range(100):  # bounded: 100 tries of at most a few ms each
        if await attempt():
            return result[0]
        await asyncio.sleep(0.05)
    raise AssertionError("the peer's service never became reachable")


def _odom(stamp: float, x: float = 1.0) -> Odometry:
    return Odometry(stamp, Pose2D(x, 2.0, 0.5), Twist(0.0, 0.0))


def test_a_message_repeats_another_only_when_all_but_its_stamp_is_equal_and_it_is_recent() -> None:
    assert repeats(_odom(1.05), _odom(1.0), 0.1)
    assert not repeats(_odom(1.1), _odom(1.0), 0.1)  # due again
    assert not repeats(_odom(1.05, x=1.001), _odom(1.0), 0.1)  # moved
    assert not repeats(Twist(0.3, 0.0), Twist(0.3, 0.0), 0.1)  # no stamp: a command always goes
    nan = BatteryState(1.05, float("nan"), float("nan"), PowerStatus.UNKNOWN)
    assert not repeats(nan, replace(nan, stamp=1.0), 0.1)  # NaN equals nothing: sent
    scan = LaserScan(1.05, "laser", 0.0, 0.1, 0.1, 10.0, np.ones(3, np.float32))
    assert not repeats(scan, replace(scan, stamp=1.0), 0.1)  # arrays are never compared


def test_repeat_periods_are_checked() -> None:
    with pytest.raises(ConfigError, match="repeat_every_s"):
        parse_profile("bus:\n  zenoh:\n    repeat_every_s: {/odom: 0}\n")
    assert parse_profile("").bus.zenoh.repeat_every_s["/odom"] == 0.25


async def test_an_unchanged_stream_reaches_other_processes_only_every_repeat_period() -> None:
    robot, port = unique_robot(), free_port()
    pub_settings = BusSettings(transport="zenoh", robot_id=robot, zenoh=ZenohSettings(
        listen=(f"tcp/127.0.0.1:{port}",), repeat_every_s={"/odom": 0.1}))  # fmt: skip
    sender = ZenohTransport(pub_settings)
    receiver = ZenohTransport(_settings(robot, [], [f"tcp/127.0.0.1:{port}"]))
    pub_bus, sub_bus = Bus(WallClock(), sender), Bus(WallClock(), receiver)
    try:
        far = sub_bus.subscribe(topics.ODOM, Odometry, maxsize=1000)
        near = pub_bus.subscribe(topics.ODOM, Odometry, maxsize=1000)
        await until(lambda: sender.matched(topics.ODOM), "the other process subscribed", poll=0.05)
        for i in range(50):  # a robot at rest: 1 s of 50 Hz odometry, the same pose
            pub_bus.publish(topics.ODOM, _odom(i * 0.02))
            await asyncio.sleep(0.002)
        pub_bus.publish(topics.ODOM, _odom(1.0, x=1.5))  # it moves: sent at once
        await until(lambda: far.pending() >= 11, "the other process got the stream", poll=0.05,
                    detail=lambda: f"got {far.pending()}, sent {sender.sent}, held {sender.held_back}")
        await asyncio.sleep(0.3)  # nothing more is on its way
        stamps = [round(far.get_nowait().stamp, 2) for _ in range(far.pending())]  # type: ignore[union-attr]
        assert stamps == [0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0]
        assert near.pending() == 51  # inside the process every message arrives
        assert sender.held_back == 40
    finally:
        sender.close()
        receiver.close()
