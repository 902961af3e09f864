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
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from sage_robot.core.errors import SageError

MODES = ("--one-process", "--processes")
STOP_GRACE_S = 10.0  # SIGINT, then this long before SIGKILL (s)
LOG_TAIL_CHARS = 400  # of a robot that ended early, quoted in the error


def _wakes(pid: str) -> int:
    """Voluntary context switches of every thread of ``pid`` (how often its threads slept and
    were woken), 0 when it ended meanwhile."""
    total = 0
    try:
        tids = os.listdir(f"/proc/{pid}/task")
    except OSError:
        return 0
    for tid in tids:
        try:
            status = Path(f"/proc/{pid}/task/{tid}/status").read_text()
        except OSError:
            continue
        for line in status.splitlines():
            if line.startswith("voluntary_ctxt_switches:"):
                total += int(line.split()[1])
    return total


def _process_name(pid: str) -> str:
    """A process group's name (``--group NAME``), else the module it runs (``-m``: the last
    part of its name, ``main`` for the supervisor), else its program's name."""
    try:
        argv = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
    except OSError:
        return "?"
    for flag in (b"--group", b"-m"):
        if flag in argv[:-1]:
            return argv[argv.index(flag) + 1].decode(errors="replace").rsplit(".", 1)[-1]
    return Path(argv[0].decode(errors="replace")).name or "?"


def _session_processes(sid: int) -> Iterator[tuple[str, list[str]]]:
    """(pid, /proc/<pid>/stat fields after the name) of the living processes in session ``sid``;
    ``fields[0]`` is field 3 of proc(5), the state."""
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            stat = Path(f"/proc/{entry}/stat").read_text()
        except OSError:  # ended meanwhile
            continue
        fields = stat[stat.rfind(")") + 2 :].split()
        if int(fields[6 - 3]) == sid:
            yield entry, fields


def _cpu_ticks(fields: list[str]) -> int:
    return int(fields[14 - 3]) + int(fields[15 - 3])  # utime + stime


def session_usage(sid: int) -> dict[str, tuple[int, int]]:
    """Process name -> (utime + stime in clock ticks, voluntary wake-ups) of the living
    processes in session ``sid`` (processes of the same name summed)."""
    usage: dict[str, tuple[int, int]] = {}
    for pid, fields in _session_processes(sid):
        name = _process_name(pid)
        ticks, wakes = usage.get(name, (0, 0))
        usage[name] = (ticks + _cpu_ticks(fields), wakes + _wakes(pid))
    return usage


def session_ticks(sid: int) -> tuple[int, int]:
    """(utime + stime in clock ticks, process count) of the living processes in session ``sid``."""
    procs = list(_session_processes(sid))
    return sum(_cpu_ticks(fields) for _, fields in procs), len(procs)


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
        before = [(session_ticks(proc.pid), session_usage(proc.pid)) for _, proc, _ in procs]
        time.sleep(window_s)
        after = [(session_ticks(proc.pid), session_usage(proc.pid)) for _, proc, _ in procs]
    runs = zip(procs, before, after, strict=True)
    return [_run_summary(mode, b, a, window_s) for (mode, _, _), b, a in runs]


def _run_summary(mode: str, before: Any, after: Any, window_s: float) -> dict[str, Any]:
    """One mode's CPU over the window, in all and per process (with its wake-ups per second)."""
    hz = os.sysconf("SC_CLK_TCK")
    (t0, count), usage0 = before
    (t1, _), usage1 = after
    per = {}
    for name, (ticks, wakes) in sorted(usage1.items()):
        ticks0, wakes0 = usage0.get(name, (ticks, wakes))  # started during the window: not counted
        per[name] = {"cpu_s": round((ticks - ticks0) / hz, 2),
                     "wakes_per_s": round((wakes - wakes0) / window_s)}
    return {"mode": mode.lstrip("-"), "processes": count, "cpu_s": round((t1 - t0) / hz, 2),
            "window_s": window_s, "by_process": per}  # fmt: skip


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
