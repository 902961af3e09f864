import asyncio
import time

import pytest

from sage_robot.core.clock import SimClock


async def test_simulated_timers_are_exact_and_faster_than_real_time():
    clock = SimClock()
    ticks_a: list[float] = []
    ticks_b: list[float] = []
    clock.every(0.1, lambda: ticks_a.append(clock.now()))
    clock.every(0.25, lambda: ticks_b.append(clock.now()))
    wall0 = time.monotonic()
    await clock.run(step_s=0.01, speed=None, until=600.0)  # ten simulated minutes
    wall = time.monotonic() - wall0
    assert len(ticks_a) == 6000
    assert len(ticks_b) == 2400
    assert abs(ticks_a[-1] - 600.0) < 1e-6
    assert wall < 60.0, f"simulated 600 s took {wall:.1f} s of wall time"


async def test_sleepers_wake_in_deadline_order():
    clock = SimClock()
    order: list[str] = []

    async def sleeper(name: str, dt: float) -> None:
        await clock.sleep(dt)
        order.append(name)

    tasks = [asyncio.ensure_future(sleeper(n, d)) for n, d in (("c", 3), ("a", 1), ("b", 2))]
    await asyncio.sleep(0)
    for _ in range(4):
        await clock.step(1.0)
    await asyncio.gather(*tasks)
    assert order == ["a", "b", "c"]


async def test_run_at_a_real_time_factor():
    clock = SimClock()
    wall0 = time.monotonic()
    await clock.run(step_s=0.01, speed=10.0, until=1.0)
    wall = time.monotonic() - wall0
    assert 0.08 < wall < 1.0  # paced: never faster than asked (the upper bound is only 10x lenient)


async def test_a_paced_simulation_that_falls_behind_slows_down_instead_of_bursting():
    """After a stall (a busy machine), simulated time goes on at the asked pace, not in a burst
    that would leave work done in threads behind the simulated clock."""
    clock = SimClock()
    step_s, stall_at = 0.02, 0.1
    walls: list[tuple[float, float]] = []

    def physics(_dt: float) -> None:
        if abs(clock.now() - stall_at) < 1e-9:
            time.sleep(0.5)  # the machine stalls for half a second
        walls.append((clock.now(), time.monotonic()))

    await clock.run(step_s, speed=1.0, until=0.4, on_step=physics)
    after = [w for t, w in walls if t > stall_at + 1e-9]
    # without the stall's 0.5 s being caught up, the 14 steps after it take their 0.28 s
    assert after[-1] - after[0] >= 0.2


async def test_simulated_time_waits_for_offloaded_work():
    """Lockstep: however long a job takes on this machine, the code that offloaded it goes
    on at the simulated time it started, and the run advances only after it."""
    clock = SimClock()
    seen: list[tuple[float, float]] = []

    def slow(x: float) -> float:
        time.sleep(0.2)  # a planner on a busy machine
        return x * 2

    async def node() -> None:
        await clock.sleep(1.0)
        started = clock.now()
        result = await clock.offload(slow, 21.0)
        seen.append((started, clock.now()))
        assert result == 42.0

    stop = asyncio.Event()
    task = asyncio.get_running_loop().create_task(node())
    await asyncio.wait_for(clock.run(0.05, None, until=3.0, stop=stop), 10)
    await asyncio.wait_for(task, 1)
    (started, after), = seen
    assert started == after == 1.0  # no simulated time passed during 0.2 s of wall time
    assert clock.offloaded == 1


async def test_a_job_with_a_latency_lands_exactly_then_however_long_it_took():
    """Time runs on beside a job with a latency (the world keeps moving while a plan is
    computed) and its result is handed over at start + latency: a fast job waits for its due
    time, a slow one holds time there; two jobs due together hand over in offload order."""
    clock = SimClock()
    landed: list[tuple[str, float]] = []
    ticks: list[float] = []

    def job(name: str, wall_s: float) -> str:
        time.sleep(wall_s)
        return name

    async def caller(name: str, wall_s: float, latency_s: float) -> None:
        await clock.sleep(1.0)
        landed.append((await clock.offload(job, name, wall_s, latency_s=latency_s), clock.now()))

    async def ticker() -> None:
        while True:
            await clock.sleep(0.05)
            ticks.append(clock.now())

    loop = asyncio.get_running_loop()
    tasks = [loop.create_task(caller("slow", 0.3, 0.2)), loop.create_task(caller("fast", 0.0, 0.2)),
             loop.create_task(caller("quick", 0.0, 0.1)), loop.create_task(ticker())]
    await asyncio.wait_for(clock.run(0.05, None, until=2.0, stop=asyncio.Event()), 10)
    for t in tasks:
        t.cancel()
    assert [name for name, _ in landed] == ["quick", "slow", "fast"]
    assert [round(at, 6) for _, at in landed] == [1.1, 1.2, 1.2]
    assert any(1.0 < t < 1.2 for t in ticks)  # time ran on while the jobs ran


async def test_an_offloaded_error_reaches_the_caller_at_the_due_time():
    clock = SimClock()

    def fail() -> None:
        raise ValueError("no path")

    async def caller() -> float:
        with pytest.raises(ValueError, match="no path"):
            await clock.offload(fail, latency_s=0.3)
        return clock.now()

    task = asyncio.get_running_loop().create_task(caller())
    await asyncio.wait_for(clock.run(0.1, None, until=1.0, stop=asyncio.Event()), 10)
    assert round(await asyncio.wait_for(task, 1), 6) == 0.3


async def test_the_wall_clock_offloads_to_a_thread():
    import threading

    from sage_robot.core.clock import WallClock

    main = threading.get_ident()
    assert await WallClock().offload(threading.get_ident) != main


@pytest.mark.parametrize(("steps_per_wake", "idle"), [(1, False), (2, False), (3, False), (2, True)])
async def test_a_paced_run_wakes_once_per_steps_per_wake_and_never_runs_ahead(
    monkeypatch: pytest.MonkeyPatch, steps_per_wake: int, idle: bool
) -> None:
    """The simulator's process (process groups) takes two 10 ms steps per wake-up. The last
    step of a batch ends one step ahead of the wall time, as a single step does; none runs
    further ahead, and none later than steps_per_wake - 2 steps."""
    from types import SimpleNamespace

    import sage_robot.core.clock as clock_module

    wall = [100.0]  # a wall clock that moves only while the run sleeps
    waits: list[float] = []
    real_sleep = asyncio.sleep

    async def sleep(delay: float, result: object = None) -> object:
        if delay > 0:
            waits.append(delay)
            wall[0] += delay
        return await real_sleep(0, result)

    monkeypatch.setattr(clock_module, "time", SimpleNamespace(monotonic=lambda: wall[0]))
    monkeypatch.setattr(asyncio, "sleep", sleep)
    clock = SimClock(steps_per_wake=steps_per_wake, idle_steps_per_wake=4)
    clock.idle = idle  # the simulated hardware says nothing moves: 4 steps per wake-up
    per_wake = 4 if idle else steps_per_wake
    step_s, steps = 0.01, 24
    leads: list[float] = []
    clock_ran: list[float] = []

    def physics(dt: float) -> None:
        leads.append(clock.now() + dt - (wall[0] - 100.0))  # how far the step's end is ahead of the wall
        clock_ran.append(clock.now())

    await clock.run(step_s, speed=1.0, until=steps * step_s, on_step=physics)
    assert len(clock_ran) == steps
    assert clock_ran == pytest.approx([k * step_s for k in range(steps)])  # every 10 ms step taken
    assert len(waits) == pytest.approx(steps / per_wake, abs=1)
    assert max(leads) <= step_s + 1e-9
    assert min(leads) >= -(per_wake - 2) * step_s - 1e-9


def test_steps_per_wake_must_be_positive() -> None:
    with pytest.raises(ValueError, match="steps_per_wake"):
        SimClock(steps_per_wake=0)
    with pytest.raises(ValueError, match="idle_steps_per_wake"):
        SimClock(idle_steps_per_wake=0)
