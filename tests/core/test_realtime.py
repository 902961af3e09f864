"""Real-time priority for the motion process (``sage_robot.core.realtime``, #24).

Each case runs in a child process, so this test process's scheduling is never changed."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from typing import Any

import pytest

from sage_robot.core.realtime import raise_threads, set_fifo
from sage_robot.core.transport.keys import ZENOH_THREADS
from tests.support.sched import fifo_permitted

pytestmark = pytest.mark.skipif(not hasattr(os, "SCHED_FIFO"), reason="needs Linux scheduling")

PR_CAPBSET_DROP, CAP_SYS_NICE = 24, 23  # <linux/prctl.h>, <linux/capability.h>
# A thread started before and one after the call; every thread's policy reported.
SCRIPT = """
import json, os, sys, threading
from sage_robot.core.realtime import describe, set_fifo, set_normal

def policies():
    return sorted({describe(int(t)) for t in os.listdir("/proc/self/task")})

stop = threading.Event()
before = threading.Thread(target=stop.wait); before.start()
refused = set_fifo(int(sys.argv[1]))
after = threading.Thread(target=stop.wait); after.start()
out = {"refused": refused, "fifo": policies(), "threads": len(os.listdir("/proc/self/task"))}
set_normal()
out["normal"] = policies()
stop.set()
print(json.dumps(out))
"""


# Threads named as Zenoh's pools name theirs, and one that is not; raised to 10 (alone, then
# in a process already at SCHED_FIFO 40).
NAMED_SCRIPT = """
import ctypes, json, os, sys, threading
from sage_robot.core.realtime import describe, raise_threads, set_fifo
from sage_robot.core.transport.keys import ZENOH_THREADS

PR_SET_NAME = 15
stop, ready = threading.Event(), threading.Barrier(4)
def named(name):
    ctypes.CDLL(None).prctl(PR_SET_NAME, name.encode(), 0, 0, 0)
    ready.wait()
    stop.wait()
for name in ("app-0", "rx-1", "worker"):
    threading.Thread(target=named, args=(name,)).start()
ready.wait()

def by_name():
    out = {}
    for t in os.listdir("/proc/self/task"):
        with open(f"/proc/self/task/{t}/comm") as f:
            out[f.read().strip()] = describe(int(t))
    return out

out = {"raised": raise_threads(10, ZENOH_THREADS), "after": by_name()}
if sys.argv[1] == "higher":
    set_fifo(40)
    out["again"] = raise_threads(10, ZENOH_THREADS)
    out["kept"] = by_name()
stop.set()
print(json.dumps(out))
"""


def _named(case: str, unprivileged: bool = False) -> dict[str, Any]:
    out = subprocess.run([sys.executable, "-c", NAMED_SCRIPT, case], capture_output=True, text=True,
                         timeout=60, check=True, preexec_fn=_drop_rights if unprivileged else None)
    result: dict[str, Any] = json.loads(out.stdout)
    return result


def _drop_rights() -> None:
    """No RLIMIT_RTPRIO, and (root) no CAP_SYS_NICE after the exec."""
    import ctypes
    import resource

    resource.setrlimit(resource.RLIMIT_RTPRIO, (0, 0))
    if os.geteuid() == 0:
        ctypes.CDLL(None, use_errno=True).prctl(PR_CAPBSET_DROP, CAP_SYS_NICE, 0, 0, 0)


def test_zenohs_threads_are_raised_by_name_and_a_higher_priority_is_kept() -> None:
    if not fifo_permitted():
        pytest.skip("this machine does not let a process take SCHED_FIFO (needs CAP_SYS_NICE or LimitRTPRIO)")
    out = _named("higher")
    assert out["raised"] == [2, None]
    after = out["after"]
    assert (after["app-0"], after["rx-1"]) == ("SCHED_FIFO 10", "SCHED_FIFO 10")
    assert after["worker"] == "normal"  # not one of Zenoh's
    assert out["again"] == [0, None]  # already at 40: not lowered to 10
    assert set(out["kept"].values()) == {"SCHED_FIFO 40"}


def test_zenohs_threads_without_the_right_stay_normal_and_say_why() -> None:
    out = _named("alone", unprivileged=True)
    count, why = out["raised"]
    assert count == 0
    assert "SCHED_FIFO 10 not permitted" in why
    assert set(out["after"].values()) == {"normal"}


def _run(priority: int, unprivileged: bool = False) -> dict[str, object]:
    out = subprocess.run([sys.executable, "-c", SCRIPT, str(priority)], capture_output=True, text=True,
                         timeout=60, check=True, preexec_fn=_drop_rights if unprivileged else None)
    result: dict[str, object] = json.loads(out.stdout)
    return result


def test_every_thread_takes_the_priority_and_gives_it_back() -> None:
    if not fifo_permitted():
        pytest.skip("this machine does not let a process take SCHED_FIFO (needs CAP_SYS_NICE or LimitRTPRIO)")
    out = _run(40)
    assert out["refused"] is None
    assert out["threads"] == 3  # the main thread, one started before the call, one after
    assert out["fifo"] == ["SCHED_FIFO 40"]
    assert out["normal"] == ["normal"]


def test_without_the_right_it_says_why_and_changes_nothing() -> None:
    out = _run(40, unprivileged=True)
    assert isinstance(out["refused"], str)
    assert "SCHED_FIFO 40 not permitted" in out["refused"]
    assert "CAP_SYS_NICE" in out["refused"]
    assert out["fifo"] == ["normal"]


def test_a_priority_out_of_range_is_refused_by_name() -> None:
    assert set_fifo(0) == "real-time priority 0 is not in 1..99"
    assert set_fifo(100) == "real-time priority 100 is not in 1..99"
    assert raise_threads(0, ZENOH_THREADS) == (0, "real-time priority 0 is not in 1..99")
