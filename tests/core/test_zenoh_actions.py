"""Bus actions between two processes over Zenoh (loopback): goal, feedback, result, cancel,
preempt, and a server process killed mid-goal.

The peer (:mod:`tests.core.zenoh_peer`) serves :data:`COUNT`; this process is the client,
through the same ``bus.actions`` API as in one process.
"""

from __future__ import annotations

import asyncio
import os
import signal
import time
from collections.abc import Iterator
from typing import Any

import pytest

pytest.importorskip("zenoh")

from sage_robot.core.actions import GoalHandle, GoalStatus
from sage_robot.core.bus import Bus
from sage_robot.core.clock import WallClock
from sage_robot.core.config.bus import BusSettings, ZenohSettings
from sage_robot.core.errors import ServiceUnavailable
from sage_robot.core.msgs import Text
from sage_robot.core.transport import actions as zactions
from sage_robot.core.transport import wire
from sage_robot.core.transport.zenoh_bus import ZenohTransport
from tests.core.zenoh_peer import COUNT, free_port, running_peer, unique_robot
from tests.support.waits import until

RESULT_S = 10.0  # bound on a short goal's result on a loaded machine (wall s)
GONE_BOUND_S = 5.0  # a killed server's goal ends within this (wall s; typically well under 1 s)


@pytest.fixture
def client() -> Iterator[tuple[Bus, Any]]:
    """A bus in this process connected to a peer process that serves COUNT."""
    robot, port = unique_robot(), free_port()
    with running_peer(robot, port) as proc:
        settings = BusSettings(
            transport="zenoh",
            robot_id=robot,
            zenoh=ZenohSettings(listen=(), connect=(f"tcp/127.0.0.1:{port}",)),
        )
        transport = ZenohTransport(settings)
        bus = Bus(WallClock(), transport)
        try:
            yield bus, proc
        finally:
            transport.close()


async def _served(bus: Bus) -> None:
    await until(lambda: bus.actions.has(COUNT), "the peer's action is known here", poll=0.02)


async def _feedback(handle: GoalHandle) -> list[str]:
    return [msg.data async for msg in handle.feedback()]


async def test_a_goal_in_another_process_sends_feedback_and_its_result(client: tuple[Bus, Any]) -> None:
    bus, _ = client
    assert not bus.actions.has("nobody_serves_this")
    with pytest.raises(ServiceUnavailable, match="nobody_serves_this"):
        await bus.actions.send_goal("nobody_serves_this", Text("1"))
    await _served(bus)
    handle = await bus.actions.send_goal(COUNT, Text("5"))
    assert bus.actions.active(COUNT) is handle
    feedback = await asyncio.wait_for(_feedback(handle), RESULT_S)
    result = await handle.result(RESULT_S)
    assert result.status is GoalStatus.SUCCEEDED
    assert result.value == Text("counted 5")
    assert feedback == ["1", "2", "3", "4", "5"]  # in order, none lost, none after the result
    assert bus.actions.active(COUNT) is None
    failed = await (await bus.actions.send_goal(COUNT, Text("fail"))).result(RESULT_S)
    assert (failed.status, failed.message) == (GoalStatus.ABORTED, "asked to fail")


async def test_cancel_and_preempt_cross_processes(client: tuple[Bus, Any]) -> None:
    bus, _ = client
    await _served(bus)
    first = await bus.actions.send_goal(COUNT, Text("forever"))
    await until(lambda: first.last_feedback is not None, "the first goal runs", poll=0.02)
    second = await bus.actions.send_goal(COUNT, Text("forever"))  # the server preempts the first
    assert (await first.result(RESULT_S)).status is GoalStatus.PREEMPTED
    await until(lambda: second.last_feedback is not None, "the second goal runs", poll=0.02)
    result = await second.cancel(timeout=RESULT_S)
    assert result.status is GoalStatus.CANCELED
    # A cancel asked for before the server even took the goal still reaches it.
    third = await bus.actions.send_goal(COUNT, Text("forever"))
    third.request_cancel()
    assert (await third.result(RESULT_S)).status is GoalStatus.CANCELED


async def test_a_goal_that_cannot_leave_the_process_ends_with_a_reason(client: tuple[Bus, Any]) -> None:
    bus, _ = client
    await _served(bus)
    handle = await bus.actions.send_goal(COUNT, object())
    result = await handle.result(RESULT_S)
    assert result.status is GoalStatus.ABORTED
    assert "cannot leave the process" in result.message


async def test_killing_the_server_process_ends_the_goal_with_an_error(client: tuple[Bus, Any]) -> None:
    bus, proc = client
    await _served(bus)
    handle = await bus.actions.send_goal(COUNT, Text("forever"))
    await until(lambda: handle.last_feedback is not None, "the goal runs", poll=0.02)
    t0 = time.monotonic()
    os.kill(proc.pid, signal.SIGKILL)
    result = await handle.result(GONE_BOUND_S)
    took = time.monotonic() - t0
    assert result.status is GoalStatus.ABORTED
    assert "went away" in result.message
    assert took < GONE_BOUND_S
    await until(lambda: not bus.actions.has(COUNT), "the dead server is forgotten", poll=0.02)
    with pytest.raises(ServiceUnavailable):
        await bus.actions.send_goal(COUNT, Text("1"))


def test_envelopes_round_trip_and_refuse_garbage() -> None:
    frames = [b"abc", b"", b"\x00" * 5]
    header = {"status": "executing", "n": 3}
    assert zactions.unpack(zactions.pack(header, frames)) == (header, frames)
    for bad in (b"", b"\x05\x00\x00\x00{}", zactions.pack(header, [b"abc"])[:-1], b"\x02\x00\x00\x00[]"):
        with pytest.raises(wire.WireError, match="bad envelope"):
            zactions.unpack(bad)


async def test_a_local_server_wins_and_nothing_goes_on_the_wire(client: tuple[Bus, Any]) -> None:
    bus, _ = client
    await _served(bus)

    async def here(goal: Text, ctx: Any) -> Text:
        ctx.feedback(Text("local feedback"))
        return Text(f"local {goal.data}")

    bus.actions.serve(COUNT, here)
    try:
        transport = bus.transport
        assert isinstance(transport, ZenohTransport)
        before = dict(transport.actions.stats)
        result = await (await bus.actions.send_goal(COUNT, Text("3"))).result(RESULT_S)
        assert result.value == Text("local 3")
        assert transport.actions.stats == before  # neither sent nor served over Zenoh
    finally:
        bus.actions.unserve(COUNT)
    assert bus.actions.has(COUNT)  # the peer's server is still there
