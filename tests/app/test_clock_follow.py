"""The follower clock: time from /clock messages (use_sim_time), on one bus and by hand."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable

import pytest

from sage_robot.core.bus import Bus
from sage_robot.core.clock import SimClock
from sage_robot.core.clock_follow import CLOCK_PERIOD_S, FollowerClock, publish_clock
from tests.support.waits import until


def test_sleepers_wake_when_clock_passes_their_deadline_and_time_never_goes_back() -> None:
    async def body() -> None:
        clock = FollowerClock()
        woke: list[float] = []

        async def sleeper() -> None:
            await clock.sleep(1.0)
            woke.append(clock.now())

        task = asyncio.get_running_loop().create_task(sleeper())
        await asyncio.sleep(0)
        clock.follow(0.5)
        await asyncio.sleep(0)
        assert woke == []
        clock.follow(1.02)
        await until(lambda: woke, "the sleeper woke")
        assert woke == [1.02]
        clock.follow(0.3)  # a late message: time stays
        assert clock.now() == 1.02
        await task

    asyncio.run(body())


def test_a_follower_keeps_the_simulators_time_through_clock_messages() -> None:
    async def body() -> None:
        sim = SimClock()
        bus = Bus(sim)
        follower = FollowerClock()
        sub = follower.attach(bus)
        timer = publish_clock(bus, sim)
        ticks: list[float] = []
        follower.every(0.25, lambda: ticks.append(follower.now()), "follower tick")
        for _ in range(round(1.0 / CLOCK_PERIOD_S)):
            await sim.step(CLOCK_PERIOD_S)
        await until(lambda: follower.now() >= 1.0 - 1e-9, "the follower reached 1 s")
        assert abs(follower.now() - sim.now()) < 1e-9
        assert ticks == pytest.approx([0.25, 0.5, 0.75, 1.0], abs=CLOCK_PERIOD_S)
        assert follower.ticks >= 1
        timer.cancel()
        sub.close()

    asyncio.run(body())


def test_the_clock_message_round_trips_through_json_and_the_wire() -> None:
    from sage_robot.core.msgs import from_dict, to_dict
    from sage_robot.core.msgs.clock import SimTime

    msg = SimTime(12.345)
    assert from_dict(to_dict(msg)) == msg
    wire = pytest.importorskip("sage_robot.core.transport.wire")
    assert wire.decode(wire.encode(msg)) == msg


def test_between_messages_a_follower_moves_on_at_the_announced_pace_but_not_past_the_limit() -> None:
    from sage_robot.core.clock_follow import AHEAD_LIMIT_S

    async def body() -> None:
        clock = FollowerClock()
        clock.follow(10.0, speed=1.0)  # the simulator runs in real time
        start = time.monotonic()
        await clock.sleep(AHEAD_LIMIT_S / 2)  # no message comes: the pace wakes it
        woke_after = time.monotonic() - start
        assert clock.now() >= 10.0 + AHEAD_LIMIT_S / 2
        assert woke_after >= AHEAD_LIMIT_S / 2 - 0.01
        # Past the limit only a message moves time: a sleeper beyond it waits for one.
        late = asyncio.get_running_loop().create_task(clock.sleep_until(10.0 + 3 * AHEAD_LIMIT_S))
        await asyncio.sleep(2 * AHEAD_LIMIT_S)
        assert clock.now() <= 10.0 + AHEAD_LIMIT_S + 1e-9
        assert not late.done()
        clock.follow(10.0 + 3 * AHEAD_LIMIT_S, speed=1.0)
        await asyncio.wait_for(late, 1.0)
        clock.follow(10.0, speed=1.0)  # a late message: time stays
        assert clock.now() >= 10.0 + 3 * AHEAD_LIMIT_S

    asyncio.run(body())


def test_a_clock_that_is_not_paced_moves_only_with_its_messages() -> None:
    async def body() -> None:
        clock = FollowerClock()
        clock.follow(5.0)  # speed 0: a simulator running as fast as it can
        await asyncio.sleep(0.05)
        assert clock.now() == 5.0

    asyncio.run(body())


def test_a_followers_timers_of_one_period_tick_together_whenever_they_started() -> None:
    """The microphone's frames and the DOA broadcast (80 ms each) wake a follower once, not
    twice: a follower's periodic jobs tick on whole multiples of their period."""

    async def body() -> None:
        clock = FollowerClock()
        clock.follow(3.013)
        first: list[float] = []
        clock.every(0.08, lambda: first.append(clock.now()), "first")
        await asyncio.sleep(0)
        clock.follow(3.031)  # 18 ms later, in the same period
        second: list[float] = []
        clock.every(0.08, lambda: second.append(clock.now()), "second")
        assert clock.phase(0.08) == pytest.approx(2.96)
        def ticked(k: int) -> Callable[[], bool]:
            return lambda: len(first) == len(second) == k

        for k, t in enumerate((3.04, 3.12, 3.2), start=1):
            clock.follow(t)
            await until(ticked(k), "both ticked")
        assert first == second == pytest.approx([3.04, 3.12, 3.2])
        assert SimClock(3.013).phase(0.08) == 3.013  # a lockstep clock keeps its phase (determinism)

    asyncio.run(body())


def test_a_timeout_that_was_not_needed_takes_its_alarm_with_it() -> None:
    """A wait with a timeout that ends early (the serial bridge's watch at rest, woken by a
    command or a read) leaves no alarm behind: the process does not wake for it later."""

    async def body() -> None:
        clock = FollowerClock()
        clock.follow(1.0, speed=1.0)
        woken = asyncio.Event()
        asyncio.get_running_loop().call_soon(woken.set)
        await clock.wait_for(woken.wait(), 0.05)
        await asyncio.sleep(0)  # the timeout's sleeper takes its cancellation
        assert clock._alarm is None  # nobody sleeps: no wake-up is scheduled
        clock.every(0.1, lambda: None, "other")  # with another sleeper, the alarm is for it
        await asyncio.sleep(0)
        other_due = clock._alarm_at
        woken.clear()
        asyncio.get_running_loop().call_soon(woken.set)
        await clock.wait_for(woken.wait(), 0.05)
        await asyncio.sleep(0)
        assert clock._alarm_at == pytest.approx(other_due)

    asyncio.run(body())
