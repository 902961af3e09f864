"""Which event loop a process runs on: asyncio's own, or uvloop's (libuv) where it helps.

A process group of the robot wakes a few dozen to a hundred times a second at rest (a
serial read, a timer, a message from another process) and does little each time, so the
loop's own work per turn is a large part of what it costs. uvloop turns the loop in C: the
process groups and their supervisor run on it (``docs/benchmarks.md``, the robot at rest,
session 22).

Single-process runs, tests and benchmarks keep asyncio's loop: after each simulated step
the lockstep clock gives woken tasks their turns until asyncio's ready queue is empty
(``core.clock._settle``), a queue uvloop does not show, so there every step would take its
full count of turns. The simulator's group does take them (it is paced: the turns are
cheap beside the ~10 ms it sleeps between steps).

uvloop comes with ``uvicorn[standard]`` (the web extra) and the ``zenoh`` extra; where it is
missing (another platform) the process runs on asyncio's loop and nothing else changes.
"""

from __future__ import annotations

import asyncio
from collections.abc import Coroutine
from typing import Any, TypeVar

T = TypeVar("T")


def run(main: Coroutine[Any, Any, T], fast: bool) -> T:
    """``asyncio.run(main)``, on uvloop's loop when ``fast`` and uvloop is installed."""
    if fast:
        try:
            import uvloop
        except ImportError:
            pass
        else:
            result: T = uvloop.run(main)  # its own asyncio.run (Python 3.10 has no asyncio.Runner)
            return result
    return asyncio.run(main)
