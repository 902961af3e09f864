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
import json
import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from typing import Any

from sage_robot.bench.web import BENCH_PASSWORD_ENV, _ClientThread

STEP_S = 0.005  # firmware model step on the wall clock (s)
DRIVE_S = 2.0  # drive this long before the fault, to reach a steady speed (s)
REPEAT_S = 0.1  # the teleop page repeats a held command this often (s)
OBSERVE_S = 6.0  # after the fault, watch this long at most (s): seed-2025's PI brakes slowly
TARGET_ZERO_S = 0.3
TARGET_REST_S = 0.6
CHILD_READY_S = 20.0  # a child process must be driving within this (s)
LOGIN_TIMEOUT_S = 30.0  # a loaded machine may be slow to answer the first request (s)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--speed", type=float, default=0.5, help="driving speed before the fault (m/s)")
    p.add_argument("--repeats", type=int, default=3, help="runs of each case (the worst is reported)")
    p.add_argument("--cases", default="", help="comma-separated subset of the cases")
    p.add_argument("--firmware", default="documented", choices=["documented", "seed-2025"],
                   help="the firmware model's dialect (and the bridge's, and the supervisor's)")


class RobotSide(threading.Thread):
    """The firmware model behind a pty, stepped in real time; records when it stops."""

    def __init__(self, firmware: str = "documented") -> None:
        super().__init__(daemon=True, name="bench-firmware")
        import numpy as np

        from sage_robot.core.config import load_profile
        from sage_robot.sim.firmware import make_firmware
        from sage_robot.sim.flat_floor import FlatFloor
        from sage_robot.sim.mcu_pty import PtyMcu

        track = load_profile(None).robot.track_width_m
        self.dialect = firmware
        self.firmware = make_firmware(firmware, track, np.random.default_rng(0))
        self.floor = FlatFloor(track)
        self.pty = PtyMcu(self.firmware)
        self.t0 = time.monotonic()
        self.stop_flag = threading.Event()
        self.lock = threading.Lock()
        self.zero_at: float | None = None  # monotonic time the firmware got a stop
        self.rest_at: float | None = None
        self.watchdog_at: float | None = None

    @property
    def port(self) -> str:
        return self.pty.port_name

    def arm(self) -> None:
        """Start watching for the next stop."""
        with self.lock:
            self.zero_at = self.rest_at = self.watchdog_at = None

    def run(self) -> None:
        fw, k = self.firmware, 0
        while not self.stop_flag.is_set():
            k += 1
            t = k * STEP_S
            wheels = fw.control_step(STEP_S, t)
            v, w = self.floor.step(STEP_S, wheels)
            fw.sense(STEP_S, v, w)
            self.pty.pump(t)
            with self.lock:
                if self.zero_at is None and fw.last_command == (0.0, 0.0) and fw.last_command_t is not None:
                    self.zero_at = self.t0 + fw.last_command_t
                if self.watchdog_at is None and fw.watchdog_tripped:
                    self.watchdog_at = self.t0 + t
                if self.rest_at is None and fw.stopped:
                    self.rest_at = self.t0 + t
            time.sleep(max(0.0, self.t0 + t - time.monotonic()))

    def speed(self) -> float:
        return 0.5 * sum(self.firmware.wheel_speeds)

    async def reset(self) -> None:
        """Between cases: a robot nothing stopped (no watchdog, no supervisor) is stopped by
        hand, as an operator would with the power switch, and allowed to come to rest."""
        from sage_robot.hardware.mcu.dialects import dialect

        if self.firmware.last_command != (0.0, 0.0):
            with self.lock:
                self.firmware.receive(dialect(self.dialect).stop())
        deadline = time.monotonic() + OBSERVE_S
        while time.monotonic() < deadline and not self.firmware.stopped:
            await asyncio.sleep(0.02)

    def close(self) -> None:
        self.stop_flag.set()
        self.join(2.0)
        self.pty.close()


@dataclass
class Outcome:
    last_command: float
    robot: RobotSide
    speed_before: float

    def as_dict(self) -> dict[str, Any]:
        r = self.robot
        zero = None if r.zero_at is None else round(max(0.0, r.zero_at - self.last_command), 3)
        rest = None if r.rest_at is None else round(r.rest_at - self.last_command, 3)
        stop_to_rest = None
        if r.rest_at is not None:
            stopped_at = r.zero_at if r.zero_at is not None else r.watchdog_at
            if stopped_at is not None:
                stop_to_rest = round(r.rest_at - stopped_at, 3)
        by = "zero command" if r.zero_at is not None else ("MCU watchdog" if r.watchdog_at else "nothing")
        return {"speed_before_mps": round(self.speed_before, 3), "zero_on_wire_s": zero,
                "at_rest_s": rest, "stop_to_rest_s": stop_to_rest, "stopped_by": by}


async def _wait(robot: RobotSide) -> None:
    deadline = time.monotonic() + OBSERVE_S
    while time.monotonic() < deadline and robot.rest_at is None:
        await asyncio.sleep(0.01)


class Operator:
    """A teleop WebSocket client in the client thread."""

    def __init__(self, clients: _ClientThread, url: str, cookie: str) -> None:
        self.clients, self.url, self.cookie = clients, url, cookie
        self.ws: Any = None
        self.last_sent = 0.0

    async def connect(self) -> None:
        from websockets.asyncio.client import connect

        async def open_() -> Any:
            return await connect(self.url + "/ws/teleop", additional_headers={"Cookie": self.cookie})

        self.ws = await self.clients.await_(open_(), 10.0)

    async def drive(self, v: float, seconds: float) -> None:
        async def repeat() -> None:
            t_end = time.monotonic() + seconds
            while time.monotonic() < t_end:
                await self.ws.send(json.dumps({"type": "control", "x": v, "z": 0.0}))
                self.last_sent = time.monotonic()
                await asyncio.sleep(REPEAT_S)

        await self.clients.await_(repeat(), seconds + 5.0)

    async def close(self) -> None:
        await self.clients.await_(self.ws.close(), 5.0)

    def freeze(self, seconds: float) -> None:
        """Block the client's loop: it neither reads nor sends."""
        self.clients.loop.call_soon_threadsafe(time.sleep, seconds)


class Stack:
    """The SAGE side in this process: serial bridge + web server on the wall clock."""

    def __init__(self, port: str, firmware: str = "documented") -> None:
        from sage_robot.core.bus import Bus
        from sage_robot.core.clock import WallClock
        from sage_robot.core.config import load_profile
        from sage_robot.core.node import NodeContext
        from sage_robot.hardware.mcu.bridge import PORT_RESOURCE

        clock = WallClock()
        overrides = {"web": {"host": "127.0.0.1", "port": 0}, "mcu": {"firmware": firmware}}
        settings = load_profile(None, overrides)
        self.ctx = NodeContext(Bus(clock), clock, settings)
        self.ctx.resources[PORT_RESOURCE] = port
        self.nodes: list[Any] = []

    async def start(self) -> tuple[Any, Any]:
        from sage_robot.hardware.mcu.bridge import SerialBridgeNode
        from sage_robot.web.node import WebNode

        bridge, web = SerialBridgeNode(self.ctx), WebNode(self.ctx)
        await bridge.setup()
        await web.setup()
        self.nodes = [bridge, web]
        while not bridge.connected:
            await asyncio.sleep(0.01)
        return bridge, web

    async def stop(self) -> None:
        for node in reversed(self.nodes):
            await node._close()
            await node.teardown()


async def _login(url: str, password: str) -> str:
    import httpx

    async with httpx.AsyncClient(base_url=url, timeout=LOGIN_TIMEOUT_S) as http:
        resp = await http.post("/api/login", json={"password": password}, headers={"Origin": url})
        resp.raise_for_status()
        return f"sage_session={resp.cookies['sage_session']}"


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


CHILD = """
import asyncio, signal, sys, time
from sage_robot.core import topics
from sage_robot.core.bus import Bus
from sage_robot.core.clock import WallClock
from sage_robot.core.config import load_profile
from sage_robot.core.msgs import Twist
from sage_robot.core.node import NodeContext
from sage_robot.hardware.mcu.bridge import PORT_RESOURCE, SerialBridgeNode

async def main():
    clock = WallClock()
    firmware = sys.argv[3] if len(sys.argv) > 3 else "documented"
    ctx = NodeContext(Bus(clock), clock, load_profile(None, {"mcu": {"firmware": firmware}}))
    ctx.resources[PORT_RESOURCE] = sys.argv[1]
    bridge = SerialBridgeNode(ctx)
    await bridge.setup()
    # SIGUSR1: the bridge's tasks die inside a live process (the publisher goes on)
    asyncio.get_running_loop().add_signal_handler(
        signal.SIGUSR1, lambda: asyncio.ensure_future(bridge._close()))
    while True:
        ctx.bus.publish(topics.CMD_VEL, Twist(float(sys.argv[2]), 0.0))
        print(time.monotonic(), flush=True)
        await asyncio.sleep(0.1)

asyncio.run(main())
"""


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
