"""Time for every node: wall time on the robot, simulated time in the simulator.

Nodes never call ``time.time()`` or a bare ``asyncio.sleep``: they ask the clock, so a
simulation can run faster than real time and a test that drives 100 m of corridor
takes seconds.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import contextvars
import heapq
import inspect
import itertools
import logging
import os
import time
import weakref
from abc import ABC, abstractmethod
from collections.abc import Awaitable, Callable
from typing import Any, TypeVar

T = TypeVar("T")

SETTLE_ROUNDS = 8  # event-loop turns given to woken tasks after each simulated step
TIME_EPS_S = 1e-9  # deadlines this close to "now" count as reached (float steps)
LAG_WARN_S = 2.0  # a paced simulation this far behind its real-time factor says so
LAG_WARN_EVERY_S = 30.0  # ... at most once per this many wall seconds
LAG_REBASE_S = 0.2  # further behind than this, a paced simulation slows down instead of catching up
# A simulated step waits for the offloaded jobs due by then with the event loop held, so that
# no task can run more or less while a job computes (that would depend on the machine's
# load); after this long it lets the loop turn once (Ctrl-C) and holds it again.
JOB_HOLD_S = 5.0
JOB_WORKERS = min(32, (os.cpu_count() or 1) + 4)  # threads for offloaded jobs (as asyncio's default)

_log = logging.getLogger("sage.clock")


async def _settle() -> None:
    """Give woken tasks up to SETTLE_ROUNDS turns of the event loop, fewer when none is left
    ready to run (most steps wake nobody): the same turns a fixed count would have given them,
    without the empty ones."""
    loop = asyncio.get_running_loop()
    ready = getattr(loop, "_ready", None)  # asyncio's queue of callbacks due this turn
    for _ in range(SETTLE_ROUNDS):
        await asyncio.sleep(0)
        if ready is not None and not ready:
            return


class Clock(ABC):
    """A source of time and of sleeps."""

    is_simulated: bool = False
    # Whether this process steps time itself, so that what happens at a simulated time
    # never depends on the machine's load (a SimClock; not a clock that follows /clock).
    is_lockstep: bool = False

    @abstractmethod
    def now(self) -> float:
        """Seconds. Wall: since the epoch. Simulated: since the simulation began."""

    @abstractmethod
    async def sleep_until(self, t: float) -> None:
        """Return once ``now() >= t``."""

    async def sleep(self, dt: float) -> None:
        await self.sleep_until(self.now() + max(0.0, dt))

    async def wait_for(self, aw: Awaitable[T], timeout: float | None) -> T:
        """Like ``asyncio.wait_for`` but the timeout runs on this clock."""
        task = asyncio.ensure_future(aw)
        if timeout is None:
            return await task
        timer = asyncio.ensure_future(self.sleep(timeout))
        try:
            done, _ = await asyncio.wait({task, timer}, return_when=asyncio.FIRST_COMPLETED)
        except asyncio.CancelledError:
            task.cancel()
            timer.cancel()
            raise
        if task in done:
            timer.cancel()
            return task.result()
        task.cancel()
        raise asyncio.TimeoutError(f"timed out after {timeout:g} s")

    def every(self, period: float, callback: Callable[[], Any], name: str = "timer") -> Timer:
        """Call ``callback`` (sync or async) every ``period`` seconds of this clock."""
        return Timer(self, period, callback, name)

    def phase(self, period: float) -> float:
        """Where a periodic job of ``period`` starting now counts its ticks from (its first tick
        is one period later): now, on this clock."""
        return self.now()

    async def offload(self, fn: Callable[..., T], *args: Any, latency_s: float = 0.0) -> T:
        """``fn(*args)`` in a worker thread (CPU work that releases the GIL: numpy, models),
        so the event loop goes on. Nodes use this, never ``asyncio.to_thread``.

        On a simulated clock the job is lockstep: with ``latency_s`` 0 simulated time does
        not pass while it runs; with ``latency_s`` > 0 (the time the job is allowed on the
        robot: a plan, a localization update) simulated time runs on beside the job up to
        ``now + latency_s``, waits there for it if need be, and the caller gets the result
        exactly then. Either way a run does not depend on how long the job took."""
        return await asyncio.to_thread(fn, *args)


def _retrieve(future: asyncio.Future[Any]) -> None:
    if not future.cancelled():
        future.exception()


class WallClock(Clock):
    """Real time. ``now()`` is the epoch time; sleeps use the monotonic clock."""

    def now(self) -> float:
        return time.time()

    async def sleep_until(self, t: float) -> None:
        await asyncio.sleep(max(0.0, t - time.time()))

    async def sleep(self, dt: float) -> None:
        await asyncio.sleep(max(0.0, dt))


class SimClock(Clock):
    """Simulated time that only moves when :meth:`step` (or :meth:`run`) advances it.

    Sleepers wait in a heap ordered by deadline, so timers fire in a deterministic order
    and a simulated hour passes as fast as the machine can compute it.
    """

    is_simulated = True
    is_lockstep = True

    def __init__(
        self, start: float = 0.0, steps_per_wake: int = 1, idle_steps_per_wake: int | None = None
    ) -> None:
        idle_steps = steps_per_wake if idle_steps_per_wake is None else idle_steps_per_wake
        for name, n in (("steps_per_wake", steps_per_wake), ("idle_steps_per_wake", idle_steps)):
            if n < 1:
                raise ValueError(f"{name} must be at least 1, not {n}")
        self._now = start
        # A paced run() takes this many steps per wake-up of the process: the last of them
        # ends one step ahead of the wall time, as a single step does; the earlier ones are
        # taken up to steps_per_wake - 2 steps after their own. While ``idle`` (set by the
        # simulated hardware: nothing commanded, nothing moving) it takes idle_steps_per_wake.
        self.steps_per_wake = steps_per_wake
        self.idle_steps_per_wake = idle_steps
        self.idle = False
        self._waiters: list[tuple[float, int, asyncio.Future[None]]] = []
        self._seq = itertools.count()
        # offloaded jobs not yet handed over -> (when they are due, the thread's future); a
        # job's state is read from its concurrent future, never from a loop callback (those
        # come in whenever the thread happens to finish)
        self._jobs: dict[int, tuple[float, concurrent.futures.Future[Any]]] = {}
        self._executor: concurrent.futures.ThreadPoolExecutor | None = None
        self._jobs_done: asyncio.Event | None = None
        # callers of finished jobs due at once, waiting to be handed their results (job order)
        self._held: dict[int, asyncio.Future[None]] = {}
        self._driven = False  # run() is stepping: results are handed over between steps
        self.offloaded = 0  # jobs run so far

    async def offload(self, fn: Callable[..., T], *args: Any, latency_s: float = 0.0) -> T:
        """As :meth:`Clock.offload`: time does not pass the job's due time (``now + latency_s``)
        until the job is done. Callers of jobs due at once take their results in the order
        they offloaded (not the order the threads happened to finish); a job with a latency
        hands its result over at its due time, in a heap with every other wake-up, so a run
        does not depend on how long the jobs took on this machine."""
        loop = asyncio.get_running_loop()
        job = next(self._seq)
        self.offloaded += 1
        due = self._now + max(0.0, latency_s)
        if self._executor is None:
            self._executor = concurrent.futures.ThreadPoolExecutor(JOB_WORKERS, thread_name_prefix="offload")
            # its idle threads end with the clock (tests make many clocks), not at exit
            weakref.finalize(self, self._executor.shutdown, wait=False)
        # The caller's context goes along (which node logs), as asyncio.to_thread does.
        thread = self._executor.submit(contextvars.copy_context().run, fn, *args)
        # Time waits for the thread itself, also when its caller was cancelled (a replan given
        # up): the thread goes on touching what it was given, so no step may pass it by.
        self._jobs[job] = (due, thread)
        thread.add_done_callback(lambda _t: self._signal_from_thread(loop))
        if latency_s > 0:
            wake: asyncio.Future[None] = loop.create_future()
            heapq.heappush(self._waiters, (due, job, wake))
            # One suspension only, the wake-up at the due time (time never passes it before
            # the thread is done): where the caller resumes never depends on when the thread
            # finished.
            await wake
            if not thread.done():  # the clock was stepped past it by hand
                await asyncio.wrap_future(thread)
            return thread.result()
        release: asyncio.Future[None] = loop.create_future()
        self._held[job] = release
        try:
            if not self._driven:  # nobody steps (yet): the thread itself, or a hand-over
                finished: asyncio.Future[Any] = asyncio.wrap_future(thread)
                # the caller takes a failure from thread.result(); this copy's is not "never retrieved"
                finished.add_done_callback(_retrieve)
                either: set[asyncio.Future[Any]] = {finished, release}
                await asyncio.wait(either, return_when=asyncio.FIRST_COMPLETED)
            if self._driven and not release.done():
                # stepping (began meanwhile, maybe): the result is handed over in offload order
                await release
            if not thread.done():  # the run ended before the hand-over: the thread itself
                await asyncio.wrap_future(thread)
            return thread.result()
        finally:
            self._held.pop(job, None)

    def _signal_from_thread(self, loop: asyncio.AbstractEventLoop) -> None:
        """A job's thread finished (runs in that thread): wake a hook's hand-over wait."""
        if not loop.is_closed():
            with contextlib.suppress(RuntimeError):  # closed in between: nobody waits any more
                loop.call_soon_threadsafe(self._job_finished_signal)

    def _job_finished_signal(self) -> None:
        if self._jobs_done is not None:
            self._jobs_done.set()

    def _running(self, job: int) -> bool:
        entry = self._jobs.get(job)
        return entry is not None and not entry[1].done()

    def _forget_done(self) -> None:
        for job in [j for j, (_, thread) in self._jobs.items() if thread.done()]:
            thread = self._jobs.pop(job)[1]
            if not thread.cancelled():
                thread.exception()  # taken by the caller's result(); not "never retrieved" if it left

    async def _wait_for_jobs(self, t: float) -> None:
        """Until no running job is due by ``t``, handing finished jobs due at once their
        results on the way (:meth:`_hand_over`). The wait holds the event loop (bounded by
        ``JOB_HOLD_S``, then one turn): no task gets more turns on a slow machine than on a
        fast one."""
        while True:
            await self._hand_over()
            self._forget_done()
            due_now = [thread for due, thread in self._jobs.values() if due <= t + TIME_EPS_S]
            if not due_now:
                return
            _, running = concurrent.futures.wait(due_now, timeout=JOB_HOLD_S)
            if running:
                await asyncio.sleep(0)

    async def _hand_over_until(self, hook: asyncio.Future[Any]) -> None:
        """Await an ``on_step`` hook, handing over results meanwhile (the node it waits for
        may be waiting for one)."""
        while not hook.done():
            await self._hand_over()
            finished = asyncio.ensure_future(self._armed().wait())  # armed before any yield
            await asyncio.wait({hook, finished}, return_when=asyncio.FIRST_COMPLETED)
            finished.cancel()
        hook.result()

    def _armed(self) -> asyncio.Event:
        """The event the next finished job sets, cleared now."""
        if self._jobs_done is None:
            self._jobs_done = asyncio.Event()
        self._jobs_done.clear()
        return self._jobs_done

    async def _hand_over(self) -> None:
        """Hand the callers of finished jobs due at once their results, strictly in offload
        order (a job still running holds back every later one), each caller going on from its
        result before the next. Results are handed over here, at the stepper's points, never
        whenever a thread happens to finish, so the interleaving is the same on every run."""
        while True:
            first = min(self._held, default=None)
            if first is None or self._running(first):  # none waiting, or the first still runs
                return
            release = self._held.pop(first)
            if not release.done():
                release.set_result(None)
            await _settle()  # the caller goes on from its result first

    def now(self) -> float:
        return self._now

    async def sleep_until(self, t: float) -> None:
        if t <= self._now:
            await asyncio.sleep(0)
            return
        fut: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        heapq.heappush(self._waiters, (t, next(self._seq), fut))
        await fut

    def next_deadline(self) -> float | None:
        """The earliest pending wake-up, or None when nobody sleeps."""
        while self._waiters and self._waiters[0][2].done():
            heapq.heappop(self._waiters)
        return self._waiters[0][0] if self._waiters else None

    def advance_to(self, t: float) -> None:
        """Set the time (never backwards) and wake everyone whose deadline has come."""
        self._now = max(self._now, t)
        while self._waiters and self._waiters[0][0] <= self._now + TIME_EPS_S:
            _, _, fut = heapq.heappop(self._waiters)
            if not fut.done():
                fut.set_result(None)

    async def step(self, dt: float) -> None:
        """Advance by ``dt`` seconds and let the woken tasks run."""
        await self._step_to(self._now + dt)

    async def _step_to(self, t: float) -> None:
        await self._wait_for_jobs(t)
        self.advance_to(t)
        await _settle()

    async def run(
        self,
        step_s: float,
        speed: float | None = 1.0,
        until: float | None = None,
        stop: asyncio.Event | None = None,
        on_step: Callable[[float], Any] | None = None,
    ) -> None:
        """Drive time forward in ``step_s`` increments.

        ``speed`` is the real-time factor (1.0 real time, 10.0 ten times faster,
        None as fast as possible). ``on_step(dt)`` runs before each advance: the
        simulator's physics step. A paced simulation that falls behind (a busy machine)
        runs slower than asked and never races to catch up: work done in threads (planning,
        localization) takes wall time, and a burst of simulated time would leave it behind.
        A paced run wakes once per ``steps_per_wake`` steps (the clock's; 1 by default), or
        per ``idle_steps_per_wake`` while the clock is marked ``idle``.
        """
        self._driven = True
        try:
            await self._run(step_s, speed, until, stop, on_step)
        finally:
            self._driven = False
            for release in self._held.values():  # nobody steps any more: hand results over now
                if not release.done():
                    release.set_result(None)

    async def _run(
        self,
        step_s: float,
        speed: float | None,
        until: float | None,
        stop: asyncio.Event | None,
        on_step: Callable[[float], Any] | None,
    ) -> None:
        wall0, sim0 = time.monotonic(), self._now
        pace_wall, pace_sim = wall0, sim0  # the pacing reference, moved on when behind
        k = 0  # steps taken: time is sim0 + k * step_s, so float errors do not accumulate
        last_warn = -LAG_WARN_EVERY_S
        while (until is None or self._now < until - TIME_EPS_S) and not (stop and stop.is_set()):
            if on_step is not None:
                result = on_step(step_s)
                if inspect.isawaitable(result):  # a hook may wait for a node (a reader in lockstep)
                    await self._hand_over_until(asyncio.ensure_future(result))
            k += 1
            await self._step_to(sim0 + k * step_s)
            if speed is not None:
                wall = time.monotonic()
                ahead = (self._now - pace_sim) / speed - (wall - pace_wall)
                if ahead > TIME_EPS_S:  # the next wake-up: when the first step of the next batch is due
                    batch = self.idle_steps_per_wake if self.idle else self.steps_per_wake
                    await asyncio.sleep(ahead + (batch - 1) * step_s / speed)
                elif -ahead > LAG_REBASE_S:
                    pace_wall, pace_sim = wall, self._now
                    if (wall - wall0) - (self._now - sim0) / speed > LAG_WARN_S:
                        last_warn = self._warn_lag(wall0, sim0, speed, last_warn)


    def _warn_lag(self, wall0: float, sim0: float, speed: float, last_warn: float) -> float:
        wall = time.monotonic()
        if wall - last_warn < LAG_WARN_EVERY_S:
            return last_warn
        factor = (self._now - sim0) / max(wall - wall0, 1e-9)
        _log.warning(
            "simulation is slower than asked: %.2fx real time instead of %.2fx (the machine is busy)",
            factor, speed,
        )
        return wall


class Timer:
    """A periodic call on a clock; missed ticks are skipped, never bunched."""

    def __init__(self, clock: Clock, period: float, callback: Callable[[], Any], name: str) -> None:
        if period <= 0:
            raise ValueError(f"timer {name!r}: period must be > 0, got {period}")
        self.clock, self.period, self.callback, self.name = clock, period, callback, name
        self.ticks = 0
        self._start = clock.phase(period)
        self._task = asyncio.get_running_loop().create_task(self._loop(), name=f"timer:{name}")

    async def _loop(self) -> None:
        n = 1  # tick n is due at start + n * period
        while True:
            next_t = self._start + n * self.period
            await self.clock.sleep_until(next_t)
            self.ticks += 1
            result = self.callback()
            if inspect.isawaitable(result):
                await result
            n += 1
            behind = int((self.clock.now() - self._start) / self.period)
            n = max(n, behind + 1)  # fell behind: skip the missed ticks

    def cancel(self) -> None:
        self._task.cancel()

    @property
    def task(self) -> asyncio.Task[None]:
        return self._task
