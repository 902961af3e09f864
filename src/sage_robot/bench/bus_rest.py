"""The CPU of the whole simulated robot at rest: one process vs process groups (part of
``sage bench bus --at-rest``, issue #24).

Each mode starts ``sage sim`` in a session of its own (web included, voice on, nobody
talking, no goal, no page open, real-time pace), waits ``warm_s`` for the models to load,
then sums utime + stime from ``/proc/<pid>/stat`` of every process in that session over
``window_s``, and ends the whole session. The two modes run at the same time (the
one-process robot on web port 8100), so both see the same machine; still read the ratio on
an otherwise quiet machine (a paced simulator on a busy one does less work per second).
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


# The one-process robot's ports, so that it runs beside the groups (which keep the defaults).
BESIDE_PROFILE = "web:\n  port: 8100\nops:\n  foxglove_port: 8766\n"


def _start(mode: str, tmp: str, profile: str | None) -> tuple[subprocess.Popen[bytes], Path]:
    env = {**os.environ, "SAGE_STATE_DIR": f"{tmp}/state", "SAGE_DATA_DIR": f"{tmp}/data",
           "SAGE_OPERATOR_PASSWORD": os.environ.get("SAGE_OPERATOR_PASSWORD", "at-rest")}  # fmt: skip
    log_path = Path(tmp) / "sim.log"
    argv = [sys.executable, "-m", "sage_robot.cli.main", *(["--profile", profile] if profile else []),
            "sim", mode]
    with log_path.open("wb") as log:
        proc = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT,
                                env=env, start_new_session=True)  # fmt: skip
    return proc, log_path


def measure(warm_s: float, window_s: float) -> list[dict[str, Any]]:
    """CPU seconds of ``sage sim --one-process`` and ``sage sim --processes``, both running at
    the same time (the first on other ports), over ``window_s`` after ``warm_s``: one after the
    other, the one-process figure alone wandered 14.2-18.8 s per 60 s between runs here, so
    the two run under the same conditions instead."""
    with contextlib.ExitStack() as stack:
        procs = []
        for mode in MODES:
            tmp = stack.enter_context(tempfile.TemporaryDirectory(prefix="sage-rest-"))
            profile = None
            if mode == "--one-process":
                profile = str(Path(tmp) / "beside.yaml")
                Path(profile).write_text(BESIDE_PROFILE)
            proc, log_path = _start(mode, tmp, profile)
            stack.callback(_end_session, proc)
            procs.append((mode, proc, log_path))
        time.sleep(warm_s)
        for mode, proc, log_path in procs:
            if proc.poll() is not None:
                tail = log_path.read_text(errors="replace")[-LOG_TAIL_CHARS:]
                raise SageError(f"sage sim {mode} ended during the warm-up (exit {proc.returncode}): {tail}")
        before = [session_ticks(proc.pid) for _, proc, _ in procs]
        time.sleep(window_s)
        after = [session_ticks(proc.pid) for _, proc, _ in procs]
    hz = os.sysconf("SC_CLK_TCK")
    return [{"mode": mode.lstrip("-"), "processes": b[1], "cpu_s": round((a[0] - b[0]) / hz, 2),
             "window_s": window_s} for (mode, _, _), b, a in zip(procs, before, after, strict=True)]


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
    runs = measure(warm_s, window_s)
    one, groups = runs
    ratio = round(groups["cpu_s"] / one["cpu_s"], 2) if one["cpu_s"] > 0 else None
    return {"runs": runs, "ratio": ratio, "target_ratio": 1.3}
