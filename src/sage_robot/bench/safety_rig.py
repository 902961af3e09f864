"""The pieces of ``sage bench safety``: the firmware model on a pty in real time, the SAGE
stack in this process, a teleop client, and the child process of the process-fault cases."""

from __future__ import annotations

import asyncio
import json
import threading
import time
from dataclasses import dataclass
from typing import Any

from sage_robot.bench.web import _ClientThread

STEP_S = 0.005  # firmware model step on the wall clock (s)
REPEAT_S = 0.1  # the teleop page repeats a held command this often (s)
OBSERVE_S = 6.0  # after the fault, watch this long at most (s): seed-2025's PI brakes slowly
LOGIN_TIMEOUT_S = 30.0  # a loaded machine may be slow to answer the first request (s)


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
