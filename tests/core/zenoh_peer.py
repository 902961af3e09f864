"""A second robot process for the Zenoh tests (run as a script, not collected by pytest).

``python tests/core/zenoh_peer.py ROBOT_ID PORT [CONNECT]``: a bus on the wall clock with a
Zenoh transport listening on 127.0.0.1:PORT. It publishes a 360-beam ``/scan`` at
:data:`SCAN_HZ`, the latched ``/sage/health`` and a building-sized latched ``/map`` once,
answers every ``/cmd_vel`` it hears with ``/peer/heard`` (the speed as text), serves
:data:`UPPER` and the action :data:`COUNT`, prints ``ready`` and runs until stdin closes
(the test ends it) or :data:`MAX_RUN_S` passes. The operator password is
``$SAGE_OPERATOR_PASSWORD``.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import selectors
import socket
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Iterator

import numpy as np

from sage_robot.core import topics
from sage_robot.core.actions import ActionAborted, GoalContext
from sage_robot.core.bus import Bus, Topic
from sage_robot.core.clock import WallClock
from sage_robot.core.config.bus import BusSettings, ZenohSettings
from sage_robot.core.msgs import HealthReport, LaserScan, NodeHealth, OccupancyGrid, Pose2D, Text, Twist
from sage_robot.core.transport.zenoh_bus import ZenohTransport

SCAN_HZ = 20.0
MAP_SHAPE = (1600, 2000)  # rows, columns: the shipped building's grid
SCAN_BEAMS = 360
MAX_RUN_S = 120.0  # a forgotten peer ends by itself
READY_S = 60.0  # bound on the peer's start (imports on a loaded machine)
STOP_S = 10.0
HEARD = Topic("/peer/heard", Text)
UPPER = "/peer/upper"  # service: Text -> Text in capitals; "boom" fails, "slow" takes 5 s
SLOW_S = 5.0
COUNT = "peer_count"  # action: Text("N") -> feedback Text("1") .. Text("N"), result Text("counted N");
# "forever" counts until cancelled, "fail" aborts with "asked to fail"
COUNT_STEP_S = 0.05
PASSWORD = "peer-test-password"


def big_map() -> OccupancyGrid:
    """The latched /map the peer publishes once: as large as the shipped building's (2000 x 1600
    cells, 3.2 MB), far more than one Zenoh batch (64 kB), with a pattern to check."""
    data = (np.arange(MAP_SHAPE[0] * MAP_SHAPE[1], dtype=np.int64) % 101).astype(np.int8).reshape(MAP_SHAPE)
    return OccupancyGrid(0.0, "map", 0.05, Pose2D(0.0, 0.0, 0.0), data)


def free_port() -> int:
    """A TCP port free on 127.0.0.1 now (each test its own: parallel runs do not cross)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


def unique_robot() -> str:
    """A robot id no other test uses: its own Zenoh key prefix."""
    return f"t{uuid.uuid4().hex[:12]}"


@contextlib.contextmanager
def running_peer(robot: str, port: int) -> Iterator[subprocess.Popen[str]]:
    """This script in a subprocess, once it has printed ``ready``; stopped on exit."""
    env = {**os.environ, "SAGE_OPERATOR_PASSWORD": PASSWORD}
    proc = subprocess.Popen(
        [sys.executable, __file__, robot, str(port)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
        env=env,
    )
    try:
        _wait_ready(proc)
        yield proc
    finally:
        assert proc.stdin is not None
        proc.stdin.close()
        try:
            proc.wait(STOP_S)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(STOP_S)


def _wait_ready(proc: subprocess.Popen[str]) -> None:
    assert proc.stdout is not None
    deadline = time.monotonic() + READY_S
    with selectors.DefaultSelector() as sel:
        sel.register(proc.stdout, selectors.EVENT_READ)
        while time.monotonic() < deadline:
            if sel.select(timeout=deadline - time.monotonic()):
                line = proc.stdout.readline()
                if line.strip() == "ready":
                    return
                if not line:
                    raise RuntimeError(f"the Zenoh peer exited with {proc.wait(STOP_S)} before it was ready")
    raise TimeoutError(f"the Zenoh peer did not print 'ready' within {READY_S:g} s")


async def main(robot: str, port: int, connect: list[str]) -> None:
    settings = BusSettings(
        transport="zenoh",
        robot_id=robot,
        zenoh=ZenohSettings(listen=(f"tcp/127.0.0.1:{port}",), connect=tuple(connect)),
    )
    password = os.environ.get("SAGE_OPERATOR_PASSWORD", "")
    transport = ZenohTransport(settings, lambda: password)
    bus = Bus(WallClock(), transport)
    try:
        await _serve(bus)
    finally:
        transport.close()


async def _upper(request: Text) -> Text:
    if request.data == "boom":
        raise ValueError("boom was asked for")
    if request.data == "slow":
        await asyncio.sleep(SLOW_S)
    return Text(request.data.upper())


async def _count(goal: Text, ctx: GoalContext) -> Text:
    if goal.data == "fail":
        raise ActionAborted("asked to fail")
    n = 0
    while goal.data == "forever" or n < int(goal.data):
        await asyncio.sleep(COUNT_STEP_S)
        n += 1
        ctx.feedback(Text(str(n)))
    return Text(f"counted {n}")


async def _serve(bus: Bus) -> None:
    bus.declare(topics.HEALTH, latched=True)
    bus.subscribe(topics.CMD_VEL, Twist, lambda m: bus.publish(HEARD, Text(f"{m.linear_x:g}")))
    bus.publish(topics.HEALTH, HealthReport(0.0, (NodeHealth("peer", "running", critical=True),)))
    bus.publish(topics.MAP, big_map())
    bus.serve(UPPER, _upper)
    bus.actions.serve(COUNT, _count)
    ranges = np.linspace(0.5, 5.0, SCAN_BEAMS, dtype=np.float32)
    ranges[0] = np.inf
    stdin_closed = threading.Event()

    def watch_stdin() -> None:
        sys.stdin.read()
        stdin_closed.set()

    threading.Thread(target=watch_stdin, daemon=True).start()
    loop = asyncio.get_running_loop()
    print("ready", flush=True)
    t0 = loop.time()
    while not stdin_closed.is_set() and loop.time() - t0 < MAX_RUN_S:
        scan = LaserScan(loop.time(), "laser", -np.pi, 2 * np.pi / SCAN_BEAMS, 0.15, 12.0, ranges)
        bus.publish(topics.SCAN, scan)
        await asyncio.sleep(1.0 / SCAN_HZ)


if __name__ == "__main__":
    asyncio.run(main(sys.argv[1], int(sys.argv[2]), sys.argv[3:]))
