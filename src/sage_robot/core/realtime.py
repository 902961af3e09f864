"""Real-time CPU priority for a latency-critical process (Linux ``SCHED_FIFO``).

The motion process (the serial bridge and the dead-man) must see a ``/cmd_vel`` or a stop
within a couple of milliseconds whatever else the machine is doing. Under the normal
scheduler a wake-up waits for a busy core's time slice: beside the running robot on two
cores, ``/cmd_vel`` between two processes had a p99 of 2-3.5 ms; with the receiving
process at ``SCHED_FIFO`` it preempts the others at once (``docs/benchmarks.md``).

A ``SCHED_FIFO`` thread runs until it blocks, so this is only for processes whose work is
short and mostly asleep. The kernel's real-time throttling (``/proc/sys/kernel/
sched_rt_runtime_us``, 95 % by default) keeps a runaway one from locking up the machine.

Raising a priority needs ``CAP_SYS_NICE`` or an ``RLIMIT_RTPRIO`` (systemd ``LimitRTPRIO=``;
``docs/operations.md``). Without it the calls here return the reason and change nothing:
the process runs on at the normal priority.
"""

from __future__ import annotations

import contextlib
import os
import re

FIFO_MIN, FIFO_MAX = 1, 99  # Linux SCHED_FIFO priorities
TASKS_DIR = "/proc/self/task"  # one entry per thread of this process


def _threads() -> list[int]:
    try:
        return [int(t) for t in os.listdir(TASKS_DIR)]
    except OSError:  # not Linux: this thread only
        return [0]


def set_fifo(priority: int) -> str | None:
    """Every thread of this process at ``SCHED_FIFO`` ``priority``; threads started later
    inherit it from the thread that starts them, and so do child processes. ``None`` when
    done, else why not (nothing changed)."""
    if not FIFO_MIN <= priority <= FIFO_MAX:
        return f"real-time priority {priority} is not in {FIFO_MIN}..{FIFO_MAX}"
    if not hasattr(os, "SCHED_FIFO"):
        return "this system has no SCHED_FIFO"
    param = os.sched_param(priority)
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, param)
    except OSError as exc:
        return _refusal(priority, exc)
    for tid in _threads():
        with contextlib.suppress(ProcessLookupError):  # a thread that has just ended
            os.sched_setscheduler(tid, os.SCHED_FIFO, param)
    return None


def raise_threads(priority: int, name: re.Pattern[str]) -> tuple[int, str | None]:
    """The threads of this process whose name (``comm``) matches ``name`` at ``SCHED_FIFO``
    ``priority``, leaving alone those already at that priority or higher (a real-time
    process's). Returns how many were raised, and ``None`` or why not (nothing changed then).
    Threads they start later inherit it."""
    if not FIFO_MIN <= priority <= FIFO_MAX:
        return 0, f"real-time priority {priority} is not in {FIFO_MIN}..{FIFO_MAX}"
    if not hasattr(os, "SCHED_FIFO"):
        return 0, "this system has no SCHED_FIFO"
    raised = 0
    for tid in _threads():
        if not tid or not name.match(_thread_name(tid)):
            continue
        with contextlib.suppress(ProcessLookupError):  # a thread that has just ended
            fifo = os.sched_getscheduler(tid) == os.SCHED_FIFO
            if fifo and os.sched_getparam(tid).sched_priority >= priority:
                continue
            try:
                os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(priority))
            except PermissionError as exc:
                return raised, _refusal(priority, exc)
            raised += 1
    return raised, None


def _refusal(priority: int, exc: OSError) -> str:
    return f"SCHED_FIFO {priority} not permitted ({exc.strerror}; needs CAP_SYS_NICE or LimitRTPRIO)"


def _thread_name(tid: int) -> str:
    try:
        with open(f"{TASKS_DIR}/{tid}/comm") as f:
            return f.read().strip()
    except OSError:  # ended
        return ""


def set_normal() -> None:
    """Every thread of this process back at the normal scheduler (always permitted)."""
    if not hasattr(os, "SCHED_OTHER"):
        return
    param = os.sched_param(0)
    for tid in [0, *_threads()]:
        with contextlib.suppress(ProcessLookupError):
            os.sched_setscheduler(tid, os.SCHED_OTHER, param)


def describe(pid: int = 0) -> str:
    """This process's (or ``pid``'s) scheduling, as reported: 'SCHED_FIFO 40' or 'normal'."""
    if hasattr(os, "SCHED_FIFO") and os.sched_getscheduler(pid) == os.SCHED_FIFO:
        return f"SCHED_FIFO {os.sched_getparam(pid).sched_priority}"
    return "normal"
