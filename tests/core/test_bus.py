import asyncio

import numpy as np
import pytest

from sage_robot.core import topics
from sage_robot.core.actions import ActionAborted, GoalStatus
from sage_robot.core.bus import Bus
from sage_robot.core.clock import SimClock
from sage_robot.core.errors import ServiceError, ServiceTimeout, ServiceUnavailable
from sage_robot.core.msgs import EStopState, OccupancyGrid, Pose2D, Text, Twist


async def test_topic_keeps_order_per_subscriber():
    bus = Bus()
    got: list[float] = []
    bus.subscribe("/cmd_vel", Twist, lambda m: got.append(m.linear_x), maxsize=100)
    for i in range(50):
        bus.publish("/cmd_vel", Twist(float(i), 0.0))
    await asyncio.sleep(0.01)
    assert got == [float(i) for i in range(50)]


async def test_slow_subscriber_drops_oldest_and_counts():
    bus = Bus()
    sub = bus.subscribe("/cmd_vel", Twist, maxsize=3)
    for i in range(10):
        bus.publish("/cmd_vel", Twist(float(i), 0.0))
    assert sub.dropped == 7
    assert [sub.get_nowait().linear_x for _ in range(3)] == [7.0, 8.0, 9.0]  # type: ignore[union-attr]


async def test_latched_topic_reaches_late_subscriber():
    bus = Bus()
    grid = OccupancyGrid(0.0, "map", 0.05, Pose2D(), np.zeros((4, 5), dtype=np.int8))
    bus.declare("/map", OccupancyGrid, latched=True)
    bus.publish("/map", grid)
    sub = bus.subscribe("/map", OccupancyGrid)
    assert await asyncio.wait_for(sub.get(), 1) == grid


async def test_wrong_type_is_refused():
    bus = Bus()
    bus.declare("/cmd_vel", Twist)
    with pytest.raises(TypeError, match="carries Twist"):
        bus.publish("/cmd_vel", Pose2D())


async def test_service_reply_error_unavailable_and_timeout():
    bus = Bus()

    async def double(x: int) -> int:
        return 2 * x

    async def broken(x: int) -> int:
        raise ValueError("no such place: moon")

    async def slow(x: int) -> int:
        await asyncio.sleep(10)
        return x

    bus.serve("double", double)
    bus.serve("broken", broken)
    bus.serve("slow", slow)
    assert await bus.call("double", 21) == 42
    with pytest.raises(ServiceError, match="no such place: moon"):
        await bus.call("broken", 1)
    with pytest.raises(ServiceUnavailable):
        await bus.call("missing", 1)
    with pytest.raises(ServiceTimeout):
        await bus.call("slow", 1, timeout=0.05)


async def test_service_timeout_runs_on_simulated_clock():
    clock = SimClock()
    bus = Bus(clock)

    async def never(x: int) -> int:
        await asyncio.Event().wait()
        return x

    bus.serve("never", never)
    call = asyncio.ensure_future(bus.call("never", 1, timeout=2.0))
    for _ in range(5):
        await asyncio.sleep(0)  # let the call start and arm its timeout at t = 2.0
    await clock.step(1.0)
    assert not call.done()
    await clock.step(1.5)
    with pytest.raises(ServiceTimeout):
        await asyncio.wait_for(call, 1)


async def test_action_feedback_and_result():
    bus = Bus()

    async def count(goal: int, ctx) -> str:
        for i in range(goal):
            ctx.feedback(i)
            await asyncio.sleep(0)
        return "done"

    bus.actions.serve("count", count)
    handle = await bus.actions.send_goal("count", 3)
    seen = [fb async for fb in handle.feedback()]
    result = await handle.result()
    assert seen == [0, 1, 2]
    assert result.ok
    assert result.value == "done"


async def test_action_cancel_preempt_and_abort():
    bus = Bus()
    cleaned: list[int] = []

    async def forever(goal: int, ctx) -> None:
        try:
            await asyncio.Event().wait()
        finally:
            cleaned.append(goal)

    async def refuse(goal: int, ctx) -> None:
        raise ActionAborted("the corridor to the clean room is blocked")

    bus.actions.serve("go", forever)
    bus.actions.serve("refuse", refuse)
    first = await bus.actions.send_goal("go", 1)
    await asyncio.sleep(0)
    second = await bus.actions.send_goal("go", 2)  # preempts the first
    assert (await first.result()).status is GoalStatus.PREEMPTED
    await asyncio.sleep(0)
    assert (await second.cancel()).status is GoalStatus.CANCELED
    assert cleaned == [1, 2]
    aborted = await (await bus.actions.send_goal("refuse", 0)).result()
    assert aborted.status is GoalStatus.ABORTED
    assert "clean room is blocked" in aborted.message


async def test_the_transport_is_asked_for_a_topic_while_someone_here_reads_it():
    from sage_robot.core.bus import LocalTransport

    class Recording(LocalTransport):
        def __init__(self) -> None:
            self.calls: list[tuple[str, str]] = []

        def want(self, topic: str, latched: bool) -> None:
            self.calls.append(("want", topic))

        def unwant(self, topic: str) -> None:
            self.calls.append(("unwant", topic))

    transport = Recording()
    bus = Bus(SimClock(), transport)
    a = bus.subscribe("/a", Text)
    b = bus.subscribe("/a", Text)
    a.close()
    assert transport.calls == [("want", "/a")]  # b still reads it
    b.close()
    b.close()  # a second close changes nothing
    assert transport.calls == [("want", "/a"), ("unwant", "/a")]
    bus.declare(topics.ESTOP)  # latched in its declaration: read for good
    bus.subscribe(topics.ESTOP, EStopState).close()
    assert transport.calls[-1] == ("want", topics.ESTOP)
    assert not bus.has_readers("/a")
