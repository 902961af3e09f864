"""`sage topic` and `sage status` attached over Zenoh to a running robot process (a peer
subprocess on its own key prefix and port; nothing is started by the commands)."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("zenoh")

from sage_robot.app.launcher import NodeSpec
from sage_robot.app.recording.mcap_io import read_mcap
from sage_robot.app.registry import node_class
from sage_robot.app.runtime import make_context, make_transport, run_launcher
from sage_robot.cli.main import main
from sage_robot.core import topics
from sage_robot.core.bus import LocalTransport
from sage_robot.core.config import load_profile, parse_profile
from sage_robot.core.msgs import HealthReport, LaserScan, Text
from sage_robot.core.transport.remote import RemoteRobot
from sage_robot.core.transport.zenoh_bus import ZenohTransport
from tests.core.zenoh_peer import PASSWORD, free_port, running_peer, unique_robot
from tests.support.waits import wait_until


@pytest.fixture(scope="module")
def robot_profile(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """A profile naming the running peer's robot id and endpoint (the tools' defaults)."""
    robot, port = unique_robot(), free_port()
    path = tmp_path_factory.mktemp("zenoh") / "robot.yaml"
    path.write_text(
        f"bus:\n  transport: zenoh\n  robot_id: {robot}\n  zenoh:\n    listen: [tcp/127.0.0.1:{port}]\n"
    )
    with running_peer(robot, port):
        yield str(path)


Cap = pytest.CaptureFixture[str]


def sage(capsys: Cap, *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_list_shows_the_robots_topics_and_types(robot_profile: str, capsys: Cap) -> None:
    code, out, _ = sage(capsys, "--profile", robot_profile, "topic", "list", "--json")
    assert code == 0
    topics = json.loads(out)
    assert topics["/scan"]["type"] == "LaserScan"
    assert topics["/scan"]["published"] > 0
    assert topics["/sage/health"]["type"] == "HealthReport"


def test_echo_prints_typed_messages(robot_profile: str, capsys: Cap) -> None:
    argv = ("--profile", robot_profile, "topic", "echo", "/scan")
    code, out, _ = sage(capsys, *argv, "--count", "2", "--json")
    assert code == 0
    lines = [json.loads(line) for line in out.splitlines()]
    assert [m["type"] for m in lines] == ["LaserScan", "LaserScan"]
    assert lines[0]["ranges"]["shape"] == [360]
    assert lines[1]["stamp"] > lines[0]["stamp"]
    code, out, _ = sage(capsys, *argv, "--count", "1")
    assert json.loads(out)["ranges"] == "<float32 array 360>"  # summarised for people


def test_hz_measures_the_rate(robot_profile: str, capsys: Cap) -> None:
    argv = ("--profile", robot_profile, "topic", "hz", "/scan")
    code, out, _ = sage(capsys, *argv, "--seconds", "1", "--json")
    assert code == 0
    report = json.loads(out)
    assert report["topic"] == "/scan"
    assert report["messages"] >= 2
    assert report["hz"] > 0


def test_pub_reaches_the_robot_with_the_operator_password(
    robot_profile: str, capsys: Cap, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("SAGE_OPERATOR_PASSWORD", PASSWORD)
    code, out, _ = sage(capsys, "--profile", robot_profile, "topic", "pub", "/cmd_vel", '{"linear_x": 0.125}')
    assert (code, out.strip()) == (0, "published Twist on /cmd_vel (1x)")

    settings = load_profile(robot_profile).bus
    with RemoteRobot(settings) as robot:
        robot.require_connected()
        # The peer answers each /cmd_vel it hears on /peer/heard.
        assert wait_until(lambda: robot.last("/peer/heard")) == Text("0.125")


def test_pub_with_a_wrong_password_is_refused_by_the_robot(
    robot_profile: str, capsys: Cap, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("SAGE_OPERATOR_PASSWORD", "guess")
    code, _, err = sage(capsys, "--profile", robot_profile, "topic", "pub", "/cmd_vel", '{"linear_x": 1}')
    assert code == 2
    refusal = "the robot refused the publication on /cmd_vel: wrong operator password"
    assert err.strip() == f"sage: error: {refusal}"


@pytest.mark.parametrize(
    ("argv", "why"),
    [
        (["echo", "cmd_vel"], "bad topic name 'cmd_vel'"),
        (["hz", "/scan/*"], "bad topic name"),
        (["pub", "/cmd_vel", "{linear_x: 1"], "message is not valid JSON"),
        (["pub", "/cmd_vel", "[1]"], "message must be a JSON object"),
        (["pub", "/cmd_vel", '{"linear_x": "fast"}'], "bad message for /cmd_vel: Twist.linear_x"),
        (["pub", "/not/in/table", '{"data": "x"}'], "not in the topic table"),
        (["pub", "/cmd_vel", "{}", "--rate", "0"], "--rate must be"),
    ],
)
def test_bad_input_is_one_line(
    robot_profile: str, capsys: Cap, argv: list[str], why: str
) -> None:
    code, _, err = sage(capsys, "--profile", robot_profile, "topic", *argv)
    assert code == 2
    assert why in err
    assert len(err.strip().splitlines()) == 1


def test_no_robot_is_a_bounded_one_line_error(tmp_path: Path, capsys: Cap) -> None:
    profile = tmp_path / "none.yaml"
    profile.write_text(
        f"bus:\n  robot_id: {unique_robot()}\n  zenoh:\n    listen: [tcp/127.0.0.1:{free_port()}]\n"
        "    open_timeout_s: 0.3\n"
    )
    code, _, err = sage(capsys, "--profile", str(profile), "topic", "list")
    assert code == 2
    assert "no robot answers on tcp/127.0.0.1:" in err


def test_status_reads_the_health_topic_over_zenoh(robot_profile: str, capsys: Cap) -> None:
    code, out, _ = sage(capsys, "--profile", robot_profile, "status", "--json")
    report = json.loads(out)
    assert report["via"] == "zenoh"
    assert report["nodes"]["peer"]["state"] == "running"
    assert code == 0
    code, out, _ = sage(capsys, "--profile", robot_profile, "status")
    assert out.splitlines()[1].split()[:2] == ["peer", "running"]


async def test_a_robot_on_the_zenoh_bus_answers_tools_and_closes_its_session() -> None:
    robot, port = unique_robot(), free_port()
    settings = parse_profile(
        f"sim:\n  speed: null\nbus:\n  transport: zenoh\n  robot_id: {robot}\n"
        f"  zenoh:\n    listen: [tcp/127.0.0.1:{port}]\n"
    )
    ctx = make_context(settings, simulated=True)
    transport = ctx.bus.transport
    assert isinstance(transport, ZenohTransport)
    seen: dict[str, Any] = {}

    async def attach(_launcher: Any) -> None:
        # The tool's calls block this loop: Zenoh's threads answer them from what the bus
        # has published (the launcher's first /sage/health).
        with RemoteRobot(settings.bus) as tool:
            tool.require_connected()
            seen["health"] = tool.last(str(topics.HEALTH))
            seen["topics"] = tool.topics()

    specs = [NodeSpec("heartbeat", node_class("heartbeat"))]
    await run_launcher(ctx, specs, until=1.0, after_start=attach)
    assert isinstance(seen["health"], HealthReport)
    assert [n.name for n in seen["health"].nodes] == ["heartbeat"]
    assert seen["topics"]["/sage/health"]["type"] == "HealthReport"
    assert transport.closed


def test_the_default_profile_keeps_the_bus_local() -> None:
    assert isinstance(make_transport(parse_profile("")), LocalTransport)


def test_status_falls_back_to_the_web_server_when_no_zenoh_robot_answers(
    tmp_path: Path, capsys: Cap
) -> None:
    profile = tmp_path / "local.yaml"
    profile.write_text(
        f"web:\n  port: {free_port()}\nbus:\n  robot_id: {unique_robot()}\n"
        f"  zenoh:\n    listen: [tcp/127.0.0.1:{free_port()}]\n"
    )
    code, _, err = sage(capsys, "--profile", str(profile), "status")
    assert code == 2
    assert "no robot answers at http" in err  # the web path, after the Zenoh probe found nobody
    assert len(err.strip().splitlines()) == 1


def test_record_attaches_to_a_running_robot(robot_profile: str, tmp_path: Path, capsys: Cap) -> None:
    out = tmp_path / "attached.mcap"
    argv = ("--profile", robot_profile, "record", str(out), "--attach", "--topics", "/scan", "/cmd_vel")
    code, printed, _ = sage(capsys, *argv, "--duration", "1.0")
    assert code == 0
    assert printed.startswith(f"wrote {out}")
    recorded = list(read_mcap(out))
    assert recorded
    assert {topic for topic, _, _ in recorded} == {"/scan"}  # nobody published /cmd_vel
    assert all(isinstance(msg, LaserScan) and msg.ranges.shape == (360,) for _, _, msg in recorded)


def test_topic_without_a_subcommand_shows_its_help(capsys: Cap) -> None:
    code, out, _ = sage(capsys, "topic")
    assert code == 0
    for sub in ("list", "echo", "hz", "pub"):
        assert sub in out
