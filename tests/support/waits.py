"""Bounded condition waits.

A test never sleeps for a fixed time hoping that something has happened by then: it waits
until a condition holds, for at most a generous bound, and a timeout names what it waited
for. Four flavours:

- ``wait_until`` (sync, wall clock): threads, subprocesses, servers, a browser;
- ``until`` (async, wall clock): tasks on the running event loop;
- ``sim_until`` (async, simulated clock): sleeps on a ``SimClock`` that some other task advances;
- ``sim_step_until`` (async, simulated clock): steps a ``SimClock`` that nothing else drives.

Timeouts are bounds, not expectations: a healthy run takes a small part of them, so a loaded
machine slows a test down instead of failing it.
"""

from __future__ import annotations

import asyncio
import inspect
import time
from collections.abc import Callable
from typing import Any, TypeVar

T = TypeVar("T")

WAIT_S = 10.0  # default bound on any wall-clock wait
POLL_S = 0.005  # how often a wall-clock condition is checked


def describe(cond: Callable[[], Any]) -> str:
    """The condition's source line (``lambda: nav.goals``), for a timeout message."""
    try:
        src = inspect.getsource(cond).strip()
    except (OSError, TypeError):
        return getattr(cond, "__qualname__", repr(cond))
    if "lambda" in src:  # `await until(lambda: nav.goals)` -> `lambda: nav.goals`
        src = src[src.index("lambda"):]
    return src if len(src) <= 200 else src[:197] + "..."


class _Deadline:
    """Checks a condition against a bound; the timeout message names what was awaited."""

    def __init__(self, now: Callable[[], float], timeout: float, unit: str, cond: Callable[[], Any],
                 what: str | None, detail: Callable[[], Any] | None) -> None:
        self.now, self.end, self.timeout, self.unit = now, now() + timeout, timeout, unit
        self.cond, self.what, self.detail = cond, what, detail

    def check(self) -> Any:
        """``cond()``'s value when truthy, else None; raises AssertionError once past the bound."""
        value = self.cond()
        if value:
            return value
        if self.now() > self.end:
            what = self.what or describe(self.cond)
            msg = f"timed out after {self.timeout:g} {self.unit} waiting for {what}"
            raise AssertionError(msg if self.detail is None else f"{msg}; {self.detail()}")
        return None


def wait_until(cond: Callable[[], T | None], what: str | None = None, timeout: float = WAIT_S, *,
               poll: float = POLL_S, detail: Callable[[], Any] | None = None) -> T:
    """Block (wall clock) until ``cond()`` is truthy and return its value; fail after ``timeout`` s."""
    deadline = _Deadline(time.monotonic, timeout, "s", cond, what, detail)
    while not (value := deadline.check()):
        time.sleep(poll)
    return value


async def until(cond: Callable[[], T | None], what: str | None = None, timeout: float = WAIT_S, *,
                poll: float = POLL_S, detail: Callable[[], Any] | None = None) -> T:
    """Await (wall clock) until ``cond()`` is truthy and return its value; fail after ``timeout`` s."""
    deadline = _Deadline(time.monotonic, timeout, "s", cond, what, detail)
    # A poll, not an Event: the condition is any expression over state the test cannot hook.
    while not (value := deadline.check()):  # noqa: ASYNC110
        await asyncio.sleep(poll)
    return value


async def sim_until(clock: Any, cond: Callable[[], T | None], what: str | None = None,
                    timeout_s: float = 30.0, *, step_s: float = 0.1,
                    detail: Callable[[], Any] | None = None) -> T:
    """Await (simulated time) until ``cond()`` is truthy; fail after ``timeout_s`` simulated s.

    Another task advances ``clock`` (a running ``SimClock``); this one sleeps on it.
    """
    deadline = _Deadline(clock.now, timeout_s, "simulated s", cond, what, detail)
    while not (value := deadline.check()):
        await clock.sleep(step_s)
    return value


async def sim_step_until(clock: Any, cond: Callable[[], T | None], what: str | None = None,
                         timeout_s: float = 60.0, *, step_s: float = 0.1, real_pause_s: float = 0.0,
                         detail: Callable[[], Any] | None = None) -> T:
    """Step ``clock`` (a ``SimClock`` nobody else drives) until ``cond()`` is truthy; fail after
    ``timeout_s`` simulated s. ``real_pause_s`` lets work in plain threads, which the clock does
    not wait for, catch up between steps."""
    deadline = _Deadline(clock.now, timeout_s, "simulated s", cond, what, detail)
    while not (value := deadline.check()):
        await clock.step(step_s)
        await asyncio.sleep(real_pause_s)
    return value


async def drain(turns: int = 5) -> None:
    """Let callbacks and tasks that are ready run (a few event-loop turns, no wall time)."""
    for _ in range(turns):
        await asyncio.sleep(0)
