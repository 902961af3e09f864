"""The CPU of the whole simulated robot at rest: one process vs process groups (part of
``sage bench bus --at-rest``, issue #24).

Each mode starts ``sage sim`` in a session of its own (web included, voice on, nobody
talking, no goal, no page open, real-time pace), waits ``warm_s`` for the models to load,
then sums utime + stime from ``/proc/<pid>/stat`` of every process in that session over
``window_s``, and ends the whole session. The two modes run one after the other, so read
the ratio on a quiet machine (a paced simulator on a busy one does less work per second).
Linux only (``/proc``).
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from sage_robot.core.errors import SageError

MODES = ("--one-process", "--processes")
STOP_GRACE_S = 10.0  # SIGINT, then this long before SIGKILL (s)
LOG_TAIL_CHARS = 400  # of a robot that ended early, quoted in the error


def session_ticks(sid: int) -> tuple[int, int]:
    """(utime + stime in clock ticks, process count) of the living processes in session ``sid``."""
    total = count = 0
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            stat = Path(f"/proc/{entry}/stat").read_text()
        except OSError:  # ended meanwhile
            continue
        fields = stat[stat.rfind(")") + 2 :].split()  # fields[0] is the state, field 3 of proc(5)
        if int(fields[6 - 3]) != sid:
            continue
        total += int(fields[14 - 3]) + int(fields[15 - 3])
        count += 1
    return total, count


def measure(mode: str, warm_s: float, window_s: float) -> dict[str, Any]:
    """CPU seconds of ``sage sim MODE`` over ``window_s`` after ``warm_s``."""
    with tempfile.TemporaryDirectory(prefix="sage-rest-") as tmp:
        env = {**os.environ, "SAGE_STATE_DIR": f"{tmp}/state", "SAGE_DATA_DIR": f"{tmp}/data",
               "SAGE_OPERATOR_PASSWORD": os.environ.get("SAGE_OPERATOR_PASSWORD", "at-rest")}  # fmt: skip
        log_path = Path(tmp) / "sim.log"
        with log_path.open("wb") as log:
            proc = subprocess.Popen(
                [sys.executable, "-m", "sage_robot.cli.main", "sim", mode],
                stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT, env=env,
                start_new_session=True,
            )  # fmt: skip
            try:
                time.sleep(warm_s)
                if proc.poll() is not None:
                    tail = log_path.read_text(errors="replace")[-LOG_TAIL_CHARS:]
                    raise SageError(f"sage sim {mode} ended during the warm-up "
                                    f"(exit {proc.returncode}): {tail}")
                t0, count = session_ticks(proc.pid)
                time.sleep(window_s)
                t1, _ = session_ticks(proc.pid)
            finally:
                _end_session(proc)
    hz = os.sysconf("SC_CLK_TCK")
    return {"mode": mode.lstrip("-"), "processes": count, "cpu_s": round((t1 - t0) / hz, 2),
            "window_s": window_s}  # fmt: skip


def _end_session(proc: subprocess.Popen[bytes]) -> None:
    """SIGINT to the robot's process group (its leader's, with every process it started), then
    SIGKILL to what is left after :data:`STOP_GRACE_S`."""
    try:
        os.killpg(proc.pid, signal.SIGINT)
        proc.wait(STOP_GRACE_S)
    except subprocess.TimeoutExpired:
        pass
    except ProcessLookupError:
        return
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, signal.SIGKILL)  # stragglers in the group too
    proc.wait()


def run_at_rest(warm_s: float, window_s: float) -> dict[str, Any]:
    if not Path("/proc/self/stat").exists():
        return {"skipped": "needs Linux /proc"}
    runs = [measure(mode, warm_s, window_s) for mode in MODES]
    one, groups = runs
    ratio = round(groups["cpu_s"] / one["cpu_s"], 2) if one["cpu_s"] > 0 else None
    return {"runs": runs, "ratio": ratio, "target_ratio": 1.3}
