"""Typed wiring: the type checker holds publishers and subscribers to a topic's message type
and resources to their key's type (mypy run on small snippets through its API)."""

from __future__ import annotations

import pickle
import re
import textwrap
from pathlib import Path

import pytest
from mypy import api as mypy_api

from sage_robot.core import topics
from sage_robot.core.bus import Bus, Topic
from sage_robot.core.msgs import Odometry, Twist
from sage_robot.core.resources import MissingResource, ResourceKey, Resources

SRC = Path(__file__).resolve().parents[2] / "src"

HEADER = """
from sage_robot.core import topics
from sage_robot.core.bus import Bus
from sage_robot.core.msgs import OccupancyGrid, Odometry, Pose2D, Twist
from sage_robot.core.node import Node
from sage_robot.core.resources import ResourceKey, Resources

bus = Bus()
ODOM_MSG = Odometry(0.0, Pose2D(), Twist())
"""


def mypy_errors(body: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """The error lines mypy reports for HEADER + body (line numbers of body, from 1)."""
    snippet = tmp_path / "snippet.py"
    snippet.write_text(HEADER + textwrap.dedent(body))
    monkeypatch.setenv("MYPYPATH", str(SRC))
    out, err, _ = mypy_api.run([
        "--no-incremental", "--follow-imports=silent", "--ignore-missing-imports",
        "--no-error-summary", "--show-error-codes", "--config-file=", str(snippet),
    ])  # fmt: skip
    assert not err, err
    offset = HEADER.count("\n")
    errors = []
    for line in out.splitlines():
        m = re.match(r".*snippet\.py:(\d+): error: (.*)", line)
        if m:
            errors.append(f"{int(m.group(1)) - offset}: {m.group(2)}")
    return errors


@pytest.mark.slow
def test_a_wrong_message_type_is_a_type_error_and_a_right_one_is_clean(tmp_path, monkeypatch) -> None:
    right = """
    def on_odom(msg: Odometry) -> None: ...
    bus.publish(topics.CMD_VEL, Twist(0.1, 0.0))
    bus.publish_threadsafe(topics.ODOM, ODOM_MSG)
    sub = bus.subscribe(topics.ODOM, Odometry, on_odom)
    odom: Odometry | None = sub.get_nowait()
    grid: OccupancyGrid | None = bus.latest(topics.MAP)
    bus.declare(topics.MAP, latched=True)
    bus.publish("/anything", 42)  # a plain name: untyped
    class N(Node):
        async def setup(self) -> None:
            self.subscribe(topics.ODOM, Odometry, on_odom)
            self.publish(topics.CMD_VEL, Twist())
    """
    assert mypy_errors(right, tmp_path, monkeypatch) == []

    wrong = """
    def on_twist(msg: Twist) -> None: ...
    bus.publish(topics.ODOM, Twist(0.1, 0.0))
    bus.subscribe(topics.ODOM, Twist)
    bus.subscribe(topics.ODOM, Odometry, on_twist)
    grid: OccupancyGrid | None = bus.latest(topics.ODOM)
    class N(Node):
        async def setup(self) -> None:
            self.publish(topics.CMD_VEL, ODOM_MSG)
    """
    errors = mypy_errors(wrong, tmp_path, monkeypatch)
    lines = sorted({int(e.split(":")[0]) for e in errors})
    assert lines == [3, 4, 5, 6, 9], errors
    assert any('"publish" of "Bus"' in e for e in errors), errors


@pytest.mark.slow
def test_resources_are_typed_by_their_key(tmp_path, monkeypatch) -> None:
    body = """
    COUNT = ResourceKey("count", int)
    res = Resources()
    res[COUNT] = 3
    res.set(COUNT, "three")
    n: int = res.require(COUNT)
    maybe: str | None = res.get(COUNT)
    res.get("count")
    """
    errors = mypy_errors(body, tmp_path, monkeypatch)
    assert sorted({int(e.split(":")[0]) for e in errors}) == [5, 7, 8], errors


def test_a_topic_is_its_name_and_carries_its_type() -> None:
    assert topics.ODOM == "/odom"
    assert {topics.ODOM: 1}["/odom"] == 1  # type: ignore[index]  # on purpose: a plain str finds it
    assert f"{topics.ODOM}" == "/odom"
    assert topics.ODOM.msg_type is Odometry
    copy = pickle.loads(pickle.dumps(topics.ODOM))
    assert isinstance(copy, Topic)
    assert copy.msg_type is Odometry


def test_the_bus_holds_a_topic_to_its_type_at_run_time() -> None:
    bus = Bus()
    with pytest.raises(TypeError, match="carries Odometry, got Twist"):
        bus.publish(topics.ODOM, Twist())  # type: ignore[misc]
    with pytest.raises(TypeError, match="carries Twist, not Odometry"):
        bus.declare(topics.CMD_VEL, Odometry)  # type: ignore[misc]
    assert bus.declare(topics.MAP, latched=True).latched
    with pytest.raises(TypeError, match="message type"):
        bus.declare("/untyped")  # type: ignore[call-overload]


def test_resources_take_only_keys_and_check_the_type() -> None:
    count = ResourceKey("count", int)
    res = Resources({count: 1})
    assert res[count] == 1
    assert res.get(count) == 1
    assert count in res
    with pytest.raises(TypeError, match="'count' is a int, not a str"):
        res[count] = "two"  # type: ignore[misc]
    with pytest.raises(TypeError, match="ResourceKey"):
        res.get("count")  # type: ignore[call-overload]
    assert res.pop(count) == 1
    assert res.get(count, 7) == 7
    with pytest.raises(MissingResource, match="'count'"):
        res.require(count)
    assert res.setdefault(count, 5) == 5
    assert res.setdefault(count, 6) == 5
