"""A clock that follows the simulator's ``/clock`` from another process (ROS 2's ``use_sim_time``).

When the robot runs as several processes (``sage sim --processes``) only the simulator's
process steps a :class:`~sage_robot.core.clock.SimClock`; it publishes its time on ``/clock``
and every other process takes its time from the messages: sleeps and timers wake when the
simulator's time passes their deadline. Time never goes backwards (a late or repeated
message changes nothing).

``/clock`` comes five times a second, not at every physics step: each message costs every
process a network wake-up and a turn of its loop (about 0.5 ms here); at 100 Hz following
the clock was most of what an idle process spent, and at 10 Hz still a quarter of what the
processes sent each other at rest. A message says how fast the simulator is
paced (``speed``); between messages a follower moves its time on at that rate, waking its
sleepers on a 10 ms grid (:data:`WAKE_GRID_S`), but never further than
:data:`AHEAD_LIMIT_S` past the last message (a simulator that falls behind, stops or pauses
holds its followers within that). A message without a speed (a simulator run as fast as it
can, a test) moves time only when it comes.

On one machine the process groups read the simulator's time from a shared page instead
(:mod:`sage_robot.core.clock_board`, ``board=``): no message at all, the time of the
simulator's last physics step whenever a process asks, and a follower never more than
:data:`BOARD_AHEAD_LIMIT_S` past it. Sleepers wake when the pace says their time has come;
the page is read again then, and a simulator that fell behind moves the wake-up on.

Across processes the run is not deterministic (how far a process got before the next tick
depends on the machine), which is why tests and benchmarks keep the single-process mode,
where one clock steps every node in lockstep.
"""

from __future__ import annotations

import asyncio
import math
import time
from typing import Any

from sage_robot.core import topics
from sage_robot.core.bus import Bus, Subscription
from sage_robot.core.clock import TIME_EPS_S, SimClock
from sage_robot.core.clock_board import ClockBoard
from sage_robot.core.msgs.clock import SimTime

CLOCK_PERIOD_S = 0.2  # the simulator publishes /clock this often (s, simulated)
AHEAD_LIMIT_S = CLOCK_PERIOD_S  # a follower's time runs at most this far past the last /clock
WAKE_GRID_S = 0.01  # between messages sleepers wake on this grid (s, simulated): one loop
#   wake-up serves every timer due within it, as one physics step's /clock used to
CLOCK_QUEUE = 8  # /clock messages queued for the follower (only the newest matters)
BOARD_AHEAD_LIMIT_S = 0.05  # with a shared page: how far past the simulator's last step a
#   follower's time may run (s, simulated; the page is written every 10 ms physics step)
BOARD_POLL_S = 0.02  # a sleeper's wake-up is due but the page is not there yet (a simulator
#   not started, stalled or unpaced): look again this often (s, wall)


class FollowerClock(SimClock):
    """Simulated time moved by ``/clock`` messages instead of a stepper, and between them at
    the pace they announce.

    Offloaded jobs run as on a simulated clock that nobody drives: a job with ``latency_s``
    hands its result over once the time passes its due time."""

    is_lockstep = False  # time comes from another process, paced by the wall clock

    def __init__(self, start: float = 0.0, board: ClockBoard | None = None) -> None:
        super().__init__(start)
        self.ticks = 0  # /clock messages (or new readings of the shared page) taken
        self._anchor = (start, time.monotonic())  # (simulated, monotonic wall) at the last message
        self._speed = 0.0  # simulated seconds per wall second between messages (0: wait for them)
        self._alarm: asyncio.TimerHandle | None = None
        self._alarm_at = float("inf")  # the simulated time the alarm wakes for
        self._board = board
        self._board_seq = 0
        self._limit = AHEAD_LIMIT_S if board is None else BOARD_AHEAD_LIMIT_S

    def follow(self, t: float, speed: float = 0.0) -> None:
        """The simulator's time is ``t`` and it runs ``speed`` times real time (0: unknown):
        move on to it and wake whoever is due."""
        self.ticks += 1
        self._anchor = (max(t, self._now), time.monotonic())
        self._speed = max(0.0, speed)
        self.advance_to(t)
        self._rearm()

    def phase(self, period: float) -> float:
        """Periodic jobs tick on whole multiples of their period: jobs of one period (the
        microphone's frames and the DOA broadcast, 80 ms) fall due together and the process
        wakes once for them, not once for each (each wake-up costs ~0.2 ms of CPU here)."""
        return math.floor(self.now() / period) * period

    @property
    def reads_board(self) -> bool:
        """Whether the time comes from a shared page (then ``/clock`` is not needed)."""
        return self._board is not None

    def now(self) -> float:
        self._catch_up()
        return self._now

    async def sleep_until(self, t: float) -> None:
        self._catch_up()
        if t > self._now + TIME_EPS_S and t < self._alarm_at:
            self._rearm(t)
        try:
            await super().sleep_until(t)
        except asyncio.CancelledError:  # a timeout that was not needed: its alarm goes with it
            if self._alarm is not None and t <= self._alarm_at + TIME_EPS_S:
                self._rearm()
            raise

    def _read_board(self) -> None:
        """Take the shared page's newest reading as the anchor (nobody is woken here: ``now()``
        may be asked from a worker thread)."""
        if self._board is None:
            return
        reading = self._board.read()
        if reading is None or reading.seq == self._board_seq:
            return
        self._board_seq = reading.seq
        self.ticks += 1
        self._anchor = (reading.t, reading.wall)
        self._speed = max(0.0, reading.speed)
        self._now = max(self._now, reading.t)

    def _paced(self) -> float:
        """Where the time is by the announced pace (never past the limit, never back)."""
        t0, wall0 = self._anchor
        if self._speed <= 0:
            return self._now
        ahead = min((time.monotonic() - wall0) * self._speed, self._limit)
        return max(self._now, t0 + ahead)

    def _catch_up(self) -> None:
        self._read_board()
        if self._speed > 0:
            self._now = self._paced()

    def _rearm(self, deadline: float | None = None) -> None:
        """An alarm on the loop for the earliest sleeper the pace reaches before the next
        message (``deadline``: a new sleeper's)."""
        if self._alarm is not None:
            self._alarm.cancel()
            self._alarm, self._alarm_at = None, float("inf")
        due = self.next_deadline()
        if deadline is not None:
            due = deadline if due is None else min(due, deadline)
        if due is None:
            return
        try:
            loop = asyncio.get_running_loop()
        except RuntimeError:  # no loop yet: the next message wakes it
            return
        if self._board is not None:
            self._rearm_on_board(loop, due)
            return
        t0, wall0 = self._anchor
        if self._speed <= 0 or due > t0 + AHEAD_LIMIT_S + TIME_EPS_S:
            return  # the next message wakes it
        due = min(t0 + math.ceil((due - t0) / WAKE_GRID_S - TIME_EPS_S) * WAKE_GRID_S, t0 + AHEAD_LIMIT_S)
        self._alarm_at = due
        self._alarm = loop.call_at(wall0 + (due - t0) / self._speed, self._ring)

    def _rearm_on_board(self, loop: asyncio.AbstractEventLoop, due: float) -> None:
        """With a shared page nothing is pushed: the alarm rings when the pace says ``due``
        comes (on the wake grid), and the page is read again then. A page that is not there
        yet, not paced, or late (the simulator stalled) is looked at every :data:`BOARD_POLL_S`."""
        self._read_board()
        t0, wall0 = self._anchor
        due = t0 + max(0.0, math.ceil((due - t0) / WAKE_GRID_S - TIME_EPS_S) * WAKE_GRID_S)
        when = wall0 + (due - t0) / self._speed if self._speed > 0 else -math.inf
        if when < loop.time() and not (self._speed > 0 and due <= t0 + self._limit + TIME_EPS_S):
            when = loop.time() + BOARD_POLL_S  # the page should say more by now: look again soon
        self._alarm_at = due
        self._alarm = loop.call_at(when, self._ring)

    def _ring(self) -> None:
        due = self._alarm_at  # the loop may ring a hair early: the alarm's time has come
        self._alarm, self._alarm_at = None, float("inf")
        if self._board is None:
            self.advance_to(max(self._paced(), due))
        else:  # as far as the page vouches for: a late simulator holds the sleeper back
            self._catch_up()
            self.advance_to(max(self._now, min(due, self._anchor[0] + self._limit)))
        self._rearm()

    def attach(self, bus: Bus) -> Subscription[Any]:
        """Follow ``/clock`` on ``bus`` from now on; the subscription (``close()`` it to stop)."""

        def on_clock(msg: SimTime) -> None:
            self.follow(msg.clock, msg.speed)

        return bus.subscribe(topics.CLOCK, SimTime, on_clock, maxsize=CLOCK_QUEUE)


def publish_clock(bus: Bus, clock: SimClock, speed: float | None = None) -> Any:
    """Publish ``clock``'s time on ``/clock`` every :data:`CLOCK_PERIOD_S` (the simulator's
    side), with the real-time factor it is paced at (None: not paced); the timer (``cancel()``
    it to stop). Needs a running event loop."""
    pace = float(speed or 0.0)
    return clock.every(CLOCK_PERIOD_S, lambda: bus.publish(topics.CLOCK, SimTime(clock.now(), pace)), "clock")
