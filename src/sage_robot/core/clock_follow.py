"""A clock that follows the simulator's ``/clock`` from another process (ROS 2's ``use_sim_time``).

When the robot runs as several processes (``sage sim --processes``) only the simulator's
process steps a :class:`~sage_robot.core.clock.SimClock`; it publishes its time on ``/clock``
and every other process takes its time from the last message: sleeps and timers wake when
the simulator's time passes their deadline. Time never goes backwards (a late or repeated
message changes nothing). Across processes the run is not deterministic (how far a process
got before the next tick depends on the machine), which is why tests and benchmarks keep
the single-process mode, where one clock steps every node in lockstep.
"""

from __future__ import annotations

from typing import Any

from sage_robot.core import topics
from sage_robot.core.bus import Bus, Subscription
from sage_robot.core.clock import SimClock
from sage_robot.core.msgs.clock import SimTime

CLOCK_PERIOD_S = 0.01  # the simulator publishes /clock this often (s, simulated): one physics step
CLOCK_QUEUE = 8  # /clock messages queued for the follower (only the newest matters)


class FollowerClock(SimClock):
    """Simulated time moved by ``/clock`` messages instead of a stepper.

    Offloaded jobs run as on a simulated clock that nobody drives: a job with ``latency_s``
    hands its result over once ``/clock`` passes its due time."""

    def __init__(self, start: float = 0.0) -> None:
        super().__init__(start)
        self.ticks = 0  # /clock messages taken

    def follow(self, t: float) -> None:
        """The simulator's time is ``t``: move on to it and wake whoever is due."""
        self.ticks += 1
        self.advance_to(t)

    def attach(self, bus: Bus) -> Subscription[Any]:
        """Follow ``/clock`` on ``bus`` from now on; the subscription (``close()`` it to stop)."""

        def on_clock(msg: SimTime) -> None:
            self.follow(msg.clock)

        return bus.subscribe(topics.CLOCK, SimTime, on_clock, maxsize=CLOCK_QUEUE)


def publish_clock(bus: Bus, clock: SimClock) -> Any:
    """Publish ``clock``'s time on ``/clock`` every :data:`CLOCK_PERIOD_S` (the simulator's
    side); the timer (``cancel()`` it to stop). Needs a running event loop."""
    return clock.every(CLOCK_PERIOD_S, lambda: bus.publish(topics.CLOCK, SimTime(clock.now())), "clock")
