"""`sage bench bus --at-rest` sums the CPU of a whole session of processes from /proc (#24)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from sage_robot.bench.bus_rest import _end_session, session_ticks, session_usage
from tests.support.waits import wait_until

BUSY_S = 0.5  # CPU each process burns before it sleeps (s)
BURN = f"""
import time
t = time.process_time() + {BUSY_S}
while time.process_time() < t:
    pass
"""
# A session leader that starts a child; both burn BUSY_S of CPU, then sleep.
LEADER = f"""
import subprocess, sys, time
subprocess.Popen([sys.executable, "-c", {BURN + "time.sleep(60)"!r}])
{BURN}
time.sleep(60)
"""

pytestmark = pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs Linux /proc")


def test_a_sessions_cpu_counts_its_children_and_its_end_takes_them_all() -> None:
    leader = subprocess.Popen([sys.executable, "-c", LEADER], start_new_session=True)
    burned = 2 * BUSY_S * os.sysconf("SC_CLK_TCK") * 0.9  # ticks, with some slack
    try:
        wait_until(lambda: session_ticks(leader.pid)[0] >= burned, "both processes' CPU counted", 30.0)
        assert session_ticks(leader.pid)[1] == 2, "the leader and its child"
        # per process name: both are `python -c CODE`, so one entry with both's CPU; once both
        # sleep, each has been woken at least once
        wait_until(lambda: sum(w for _, w in session_usage(leader.pid).values()) >= 2, "both asleep", 30.0)
        usage = session_usage(leader.pid)
        assert list(usage) == [Path(sys.executable).name]
        assert usage[Path(sys.executable).name][0] >= burned
    finally:
        _end_session(leader)
    wait_until(lambda: session_ticks(leader.pid)[1] == 0, "nothing of the session left", 10.0)
