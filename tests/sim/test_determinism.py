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


def _summary() -> dict[str, object]:
    out = subprocess.run(
        [sys.executable, "-m", "sage_robot.cli.main", "sim", "--headless", "--fast", "--scenario",
         "crowded_corridor", "--seed", "3", "--duration", "40", "--json"],
        capture_output=True, text=True, timeout=300,
    )
    assert out.returncode == 0, out.stderr[-2000:]
    summary: dict[str, object] = json.loads(out.stdout.strip().splitlines()[-1])
    for field in WALL_FIELDS:
        summary.pop(field)
    return summary


def test_the_same_seed_gives_the_same_run_on_a_quiet_and_a_loaded_machine() -> None:
    quiet = _summary()
    with cpu_hogs(2):
        loaded = _summary()
    assert quiet["distance_m"] and quiet["goals"], quiet  # the robot drove: a real comparison
    for field in quiet:
        assert loaded[field] == quiet[field], f"{field}: {quiet[field]!r} then {loaded[field]!r}"
