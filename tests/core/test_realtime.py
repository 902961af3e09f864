"""Real-time priority for the motion process (``sage_robot.core.realtime``, #24).

Each case runs in a child process, so this test process's scheduling is never changed."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from sage_robot.core.realtime import set_fifo
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


def _run(priority: int, unprivileged: bool = False) -> dict[str, object]:
    def drop() -> None:  # no RLIMIT_RTPRIO, and (root) no CAP_SYS_NICE after the exec
        import ctypes
        import resource

        resource.setrlimit(resource.RLIMIT_RTPRIO, (0, 0))
        if os.geteuid() == 0:
            ctypes.CDLL(None, use_errno=True).prctl(PR_CAPBSET_DROP, CAP_SYS_NICE, 0, 0, 0)

    out = subprocess.run([sys.executable, "-c", SCRIPT, str(priority)], capture_output=True, text=True,
                         timeout=60, check=True, preexec_fn=drop if unprivileged else None)
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
