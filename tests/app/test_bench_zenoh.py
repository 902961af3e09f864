"""`sage bench bus`'s Zenoh cases: the paced /cmd_vel receiver runs as the motion process (#24)."""

from __future__ import annotations

import os

import pytest

from sage_robot.core.realtime import describe

pytest.importorskip("zenoh", reason="the Zenoh cases need eclipse-zenoh (pip install 'sage-robot[zenoh]')")

from sage_robot.bench.bus_zenoh import Case, default_cases, run_cases
from tests.support.sched import fifo_permitted

MOTION_FIFO = 40
ZENOH_FIFO = 10  # processes.zenoh_realtime


def test_the_paced_cmd_vel_case_receives_at_the_motion_processs_priority() -> None:
    cases = default_cases(0.01, MOTION_FIFO)
    assert [(c.kind, c.rate_hz, c.receiver_fifo) for c in cases if c.receiver_fifo] == [
        ("cmd_vel", 1000.0, MOTION_FIFO)
    ]
    # Both processes' Zenoh threads as the robot's groups have them (processes.zenoh_realtime).
    assert {c.zenoh_fifo for c in default_cases(0.01, MOTION_FIFO, ZENOH_FIFO)} == {ZENOH_FIFO}
    result = run_cases([Case("/cmd_vel Twist", "cmd_vel", 50, 200.0, MOTION_FIFO, ZENOH_FIFO)])[0]
    assert result["received"] == 50
    if fifo_permitted():
        assert result["receiver"] == f"SCHED_FIFO {MOTION_FIFO}"
        assert result["publisher"] == f"normal, Zenoh threads SCHED_FIFO {ZENOH_FIFO}"
    else:
        assert result["receiver"].startswith(f"normal (SCHED_FIFO {MOTION_FIFO} not permitted")
        assert result["publisher"].startswith(f"normal (Zenoh threads: SCHED_FIFO {ZENOH_FIFO} not permitted")
    # the bench process itself is back at the normal priority for the cases after it
    assert describe() == "normal"
    assert all(describe(int(t)) == "normal" for t in os.listdir("/proc/self/task"))


def test_without_a_zenoh_priority_the_publisher_is_plain_normal() -> None:
    result = run_cases([Case("/cmd_vel Twist", "cmd_vel", 20, 200.0, 0, 0)])[0]
    assert (result["received"], result["receiver"], result["publisher"]) == (20, "normal", "normal")
