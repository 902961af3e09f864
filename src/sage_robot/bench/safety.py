"""Safety chain under faults: how fast the robot stops when its command is lost.

The robot side is the firmware model behind a real pty (:class:`PtyMcu`), stepped at
:data:`STEP_S` on the wall clock in a thread of its own with a flat floor under it, so
"at rest" is the model's wheels at rest and its PWM at stop. SAGE's side is the real
serial bridge and web server (wall clock); an operator drives at ``--speed`` m/s through
``/ws/teleop`` from a client thread (as a browser is another process), then a fault:

- ``socket_closed``: the operator's WebSocket closes;
- ``client_silent``: the page stops sending but the socket stays open;
- ``client_frozen``: the client's whole event loop blocks (reads nothing, sends nothing);
- ``estop``: the operator presses the e-stop mid-drive;
- ``navigator_silent``: a node that drove through ``/cmd_vel`` stops publishing (crashed):
  only the bridge's own command timeout is left;
- ``web_crashed``: the web node's tasks die without their teardown (a crash);
- ``bridge_dead_in_process``: the serial bridge's tasks die with the port open inside a
  live process that has no supervisor: only the MCU's own watchdog is left (the documented
  firmware has one; firmware without a watchdog would drive on);
- ``bridge_dead_supervised``: the same inside SAGE's process under the supervisor: the
  bridge's heartbeat stops with it and the supervisor stops the motors;
- ``process_frozen_supervised``: SAGE's process (bridge + a publisher) is frozen with
  SIGSTOP under the supervisor: the bridge's heartbeat stops and the supervisor stops the
  motors;
- ``process_killed_supervised`` / ``_unsupervised``: SAGE's process is killed with
  SIGKILL, under the supervisor (``sage up``'s default) and without it.

Per case: ``zero_on_wire_s`` (last command sent → a stop received by the firmware;
``null`` when none ever came), ``at_rest_s`` (last command → wheels at rest),
``stop_to_rest_s`` and what stopped it. Targets: zero ≤ 0.3 s, at rest ≤ 0.6 s after the
stop from 0.5 m/s.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import os
import signal
import subprocess
import sys
import time
from typing import Any

from sage_robot.bench.safety_rig import (
    CHILD,
    OBSERVE_S,
    REPEAT_S,
    Operator,
    Outcome,
    RobotSide,
    Stack,
    _login,
    _wait,
)
from sage_robot.bench.web import BENCH_PASSWORD_ENV, _ClientThread

DRIVE_S = 2.0  # drive this long before the fault, to reach a steady speed (s)
TARGET_ZERO_S = 0.3
TARGET_REST_S = 0.6
CHILD_READY_S = 20.0  # a child process must be driving within this (s)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--speed", type=float, default=0.5, help="driving speed before the fault (m/s)")
    p.add_argument("--repeats", type=int, default=3, help="runs of each case (the worst is reported)")
    p.add_argument("--cases", default="", help="comma-separated subset of the cases")
    p.add_argument("--firmware", default="documented", choices=["documented", "seed-2025"],
                   help="the firmware model's dialect (and the bridge's, and the supervisor's)")


async def _teleop_case(case: str, robot: RobotSide, speed: float, clients: _ClientThread,
                       password: str) -> dict[str, Any]:
    stack = Stack(robot.port, robot.dialect)
    bridge, web = await stack.start()
    try:
        op = Operator(clients, web.url.replace("http://", "ws://"), await _login(web.url, password))
        await op.connect()
        await op.drive(speed, DRIVE_S)
        before = robot.speed()
        robot.arm()
        if case == "socket_closed":
            await op.close()
        elif case == "client_frozen":
            op.freeze(OBSERVE_S + 0.5)
        elif case == "estop":
            await web.teleop.set_estop(True, "bench")
            op.last_sent = time.monotonic()  # the press is the last command
        elif case == "web_crashed":
            await web._close()  # its tasks die; no teardown, no goodbye stop
        elif case == "bridge_dead_in_process":
            await bridge._close()  # the bridge's tasks die with the port open
        await _wait(robot)
        out = Outcome(op.last_sent, robot, before).as_dict()
        if case == "client_frozen":
            await asyncio.sleep(0.6)  # let the client thaw before closing it
        if case != "socket_closed":
            with contextlib.suppress(Exception):  # a socket the crashed server dropped
                await op.close()
        return out
    finally:
        await stack.stop()


async def _navigator_silent(robot: RobotSide, speed: float) -> dict[str, Any]:
    from sage_robot.core import topics
    from sage_robot.core.msgs import Twist

    stack = Stack(robot.port, robot.dialect)
    await stack.start()
    try:
        t_end, last = time.monotonic() + DRIVE_S, 0.0
        while time.monotonic() < t_end:
            stack.ctx.bus.publish(topics.CMD_VEL, Twist(speed, 0.0))
            last = time.monotonic()
            await asyncio.sleep(REPEAT_S)
        before = robot.speed()
        robot.arm()
        await _wait(robot)
        return Outcome(last, robot, before).as_dict()
    finally:
        await stack.stop()


async def _process_fault(robot: RobotSide, speed: float, supervised: bool, sig: int) -> dict[str, Any]:
    """SAGE's process (bridge + publisher) gets ``sig`` (SIGKILL, SIGSTOP) mid-drive."""
    cmd = [sys.executable, "-c", CHILD, robot.port, str(speed), robot.dialect]
    if supervised:
        cmd = [sys.executable, "-m", "sage_robot.app.supervisor", "--announce",
               "--firmware", robot.dialect, "--port", robot.port, "--", *cmd]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True)
    child_pid, last = proc.pid, 0.0
    try:
        assert proc.stdout is not None
        if supervised:  # its first line names the child
            child_pid = int((await asyncio.to_thread(proc.stdout.readline)).split()[1])
        t_ready = time.monotonic() + CHILD_READY_S
        while time.monotonic() < t_ready and robot.speed() < 0.95 * speed:
            line = await asyncio.to_thread(proc.stdout.readline)
            if line.strip():
                last = float(line)
        t_end = time.monotonic() + DRIVE_S / 2  # at speed: drive on a little
        while time.monotonic() < t_end:
            last = float((await asyncio.to_thread(proc.stdout.readline)) or last)
        before = robot.speed()
        robot.arm()
        os.kill(child_pid, sig)
        await _wait(robot)
        return Outcome(last, robot, before).as_dict()
    finally:
        for pid in {child_pid, proc.pid}:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        await asyncio.to_thread(proc.wait, 10.0)


CASES = ("socket_closed", "client_silent", "client_frozen", "estop", "navigator_silent", "web_crashed",
         "bridge_dead_in_process", "bridge_dead_supervised", "process_frozen_supervised",
         "process_killed_supervised", "process_killed_unsupervised")


async def _one(case: str, robot: RobotSide, args: argparse.Namespace, clients: _ClientThread,
               password: str) -> dict[str, Any]:
    if case == "navigator_silent":
        return await _navigator_silent(robot, args.speed)
    if case.startswith("process_") or case == "bridge_dead_supervised":
        sig = {"process_frozen": signal.SIGSTOP, "bridge_dead": signal.SIGUSR1}.get(
            case.rsplit("_", 1)[0], signal.SIGKILL)
        return await _process_fault(robot, args.speed, case.endswith("_supervised"), sig)
    return await _teleop_case(case, robot, args.speed, clients, password)


def _worst(runs: list[dict[str, Any]]) -> dict[str, Any]:
    def key(r: dict[str, Any]) -> float:
        return float("inf") if r["at_rest_s"] is None else float(r["at_rest_s"])

    slowest: dict[str, Any] = max(runs, key=key)
    worst = dict(slowest)
    zeros = [r["zero_on_wire_s"] for r in runs]
    worst["zero_on_wire_s_all"] = zeros
    worst["at_rest_s_all"] = [r["at_rest_s"] for r in runs]
    worst["meets_targets"] = all(
        z is not None and z <= TARGET_ZERO_S and r["stop_to_rest_s"] is not None
        and r["stop_to_rest_s"] <= TARGET_REST_S for z, r in zip(zeros, runs, strict=True)
    )
    return worst


async def _main(args: argparse.Namespace) -> dict[str, Any]:
    password = os.environ.get(BENCH_PASSWORD_ENV) or "bench-" + os.urandom(6).hex()
    os.environ[BENCH_PASSWORD_ENV] = password
    cases = [c for c in (args.cases.split(",") if args.cases else CASES) if c]
    unknown = [c for c in cases if c not in CASES]
    if unknown:
        from sage_robot.core.errors import SageError

        raise SageError(f"unknown case(s) {', '.join(unknown)}; cases: {', '.join(CASES)}")
    robot = RobotSide(args.firmware)
    robot.start()
    clients = _ClientThread()
    results: dict[str, Any] = {}
    try:
        for case in cases:
            runs = []
            for _ in range(args.repeats):
                runs.append(await _one(case, robot, args, clients, password))
                await robot.reset()
            results[case] = _worst(runs)
    finally:
        clients.close()
        robot.close()
    return {
        "bench": "safety",
        "firmware": args.firmware,
        "speed_mps": args.speed,
        "repeats": args.repeats,
        "targets": {"zero_on_wire_s": TARGET_ZERO_S, "stop_to_rest_s": TARGET_REST_S},
        "cases": results,
        "load_avg_1m": round(os.getloadavg()[0], 2),
    }


def run(args: argparse.Namespace) -> dict[str, Any]:
    return asyncio.run(_main(args))
