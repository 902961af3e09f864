"""Same seed, same run: a scenario on the simulated clock gives the same summary twice, the
second time beside two CPU hogs (work offloaded through the clock is lockstep, the serial
bridge reads its pty at fixed simulated times, offloaded jobs' inputs are taken on the loop).
"""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager

import pytest

WALL_FIELDS = ("wall_time_s", "real_time_factor")  # the only fields allowed to differ
HOG = "import time\nt = time.monotonic()\nwhile time.monotonic() - t < 120: pass"


@contextmanager
def cpu_hogs(n: int) -> Iterator[None]:
    procs = [subprocess.Popen([sys.executable, "-c", HOG]) for _ in range(n)]
    try:
        yield
    finally:
        for p in procs:
            p.kill()
            p.wait(10)


def _summary(*pace: str) -> dict[str, object]:
    out = subprocess.run(
        [sys.executable, "-m", "sage_robot.cli.main", "sim", "--headless", *(pace or ("--fast",)),
         "--scenario", "crowded_corridor", "--seed", "3", "--duration", "40", "--json"],
        capture_output=True, text=True, timeout=300,
    )
    assert out.returncode == 0, out.stderr[-2000:]
    summary: dict[str, object] = json.loads(out.stdout.strip().splitlines()[-1])
    for field in WALL_FIELDS:
        summary.pop(field)
    return summary


@pytest.fixture(scope="module")
def quiet() -> dict[str, object]:
    summary = _summary()
    assert summary["distance_m"], summary  # the robot drove: a real comparison
    assert summary["goals"], summary
    return summary


def _same(first: dict[str, object], second: dict[str, object]) -> None:
    assert first.keys() == second.keys()
    for field in first:
        assert second[field] == first[field], f"{field}: {first[field]!r} then {second[field]!r}"


def test_the_same_seed_gives_the_same_run_on_a_quiet_and_a_loaded_machine(quiet: dict[str, object]) -> None:
    with cpu_hogs(2):
        loaded = _summary()
    _same(quiet, loaded)


def test_a_paced_run_gives_the_same_run_as_a_fast_one(quiet: dict[str, object]) -> None:
    """--speed 10 sleeps between steps (and slows down where the machine cannot keep up):
    the same simulated run, only spread over more wall time."""
    _same(quiet, _summary("--speed", "10"))
