"""The bus between two processes over Zenoh on loopback (part of `sage bench bus`).

This process runs a bus with a :class:`ZenohTransport` listening on a free loopback port and
subscribes; a child process (this module run with ``--child``) runs its own bus, connects,
and publishes through ``bus.publish`` — so each message pays the whole path: encoding,
Zenoh, decoding on Zenoh's thread, the hop onto the receiving loop and the subscriber's
callback. Latency is the receive time minus the send time, both on the machine's monotonic
clock (``time.perf_counter`` is CLOCK_MONOTONIC on Linux, shared by processes): the message's
stamp (``Twist`` carries it in ``angular_z``, a float64 with µs resolution).

Each case is either *paced* (a fixed rate, the latency a node sees) or *flood* (as fast as
the publisher can, the throughput; its latency includes the queue that builds up).

The paced ``/cmd_vel`` case receives as the robot's motion process does: at the real-time priority
the profile gives it (``processes.realtime``, :mod:`sage_robot.core.realtime`) where this
process may take it, and say so (``receiver``); the publisher runs at the normal priority, as
the navigator and the web server do. The other cases' receivers (navigation, the pages; a
flood, which would hold a real-time receiver's core) run at the normal priority. In both
processes Zenoh's own threads run at ``processes.zenoh_realtime``, as in the robot's groups
(``publisher`` says what the publisher's got).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import socket
import sys
import time
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

SCAN_BEAMS = 360
FRAME_W, FRAME_H = 480, 270  # the web page's camera frame
JPEG_QUALITY = 80
RECEIVE_TIMEOUT_S = 60.0  # a case's bound on waiting for the last message
CHILD_START_S = 60.0
DRAIN_S = 1.0  # after the publisher exited, wait this long for messages still on their way
SETTLE_S = 0.5  # after the subscription matched, before the first message is sent
BURST = 10  # flood: messages published between two yields to the loop
TOPIC = "/bench/zenoh"


@dataclass(frozen=True)
class Case:
    label: str  # the message, as reported
    kind: str  # cmd_vel, scan or camera
    messages: int
    rate_hz: float | None  # None: flood
    receiver_fifo: int = 0  # the receiving process's SCHED_FIFO priority (0: normal)
    zenoh_fifo: int = 0  # both processes' Zenoh threads' SCHED_FIFO priority (0: normal)


def default_cases(scale: float, motion_fifo: int = 0, zenoh_fifo: int = 0) -> list[Case]:
    """The cases; paced ``/cmd_vel`` received at ``motion_fifo`` (the motion group's
    ``processes.realtime``); Zenoh's threads at ``zenoh_fifo`` (``processes.zenoh_realtime``)."""

    def n(count: int) -> int:
        return max(10, int(count * scale))

    return [
        Case("/cmd_vel Twist", "cmd_vel", n(3000), 1000.0, motion_fifo, zenoh_fifo),
        Case("/cmd_vel Twist", "cmd_vel", n(20000), None, 0, zenoh_fifo),
        Case(f"/scan LaserScan {SCAN_BEAMS} beams", "scan", n(500), 50.0, 0, zenoh_fifo),
        Case(f"/scan LaserScan {SCAN_BEAMS} beams", "scan", n(5000), None, 0, zenoh_fifo),
        Case(f"camera CompressedImage {FRAME_W}x{FRAME_H} JPEG", "camera", n(150), 30.0, 0, zenoh_fifo),
        Case(f"camera CompressedImage {FRAME_W}x{FRAME_H} JPEG", "camera", n(1000), None, 0, zenoh_fifo),
    ]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


def settings_for(robot: str, listen: list[str], connect: list[str]) -> Any:
    from sage_robot.core.config.bus import BusSettings, ZenohSettings

    return BusSettings(
        transport="zenoh", robot_id=robot, zenoh=ZenohSettings(listen=tuple(listen), connect=tuple(connect))
    )


def _message_maker(kind: str) -> Any:
    """A function from a send time to the case's message."""
    from sage_robot.core.msgs import CompressedImage, LaserScan, Twist

    if kind == "cmd_vel":
        return lambda t: Twist(0.3, t)
    if kind == "scan":
        ranges = np.linspace(0.2, 8.0, SCAN_BEAMS, dtype=np.float32)
        scan = LaserScan(0.0, "laser", -np.pi, 2 * np.pi / SCAN_BEAMS, 0.15, 12.0, ranges)
        return lambda t: replace(scan, stamp=t)
    frame = CompressedImage(0.0, "camera", "jpeg", _jpeg())
    return lambda t: replace(frame, stamp=t)


def _jpeg() -> bytes:
    """A 480x270 JPEG of a gradient with noise (about the size of a camera frame)."""
    import io

    from PIL import Image

    rng = np.random.default_rng(0)
    x = np.linspace(0, 255, FRAME_W)[None, :, None]
    y = np.linspace(0, 255, FRAME_H)[:, None, None]
    img = np.clip(0.5 * x + 0.5 * y + rng.normal(0, 12, (FRAME_H, FRAME_W, 3)), 0, 255).astype(np.uint8)
    buf = io.BytesIO()
    Image.fromarray(img).save(buf, format="JPEG", quality=JPEG_QUALITY)
    return buf.getvalue()


def _stamp(msg: Any) -> float:
    return float(msg.angular_z if hasattr(msg, "angular_z") else msg.stamp)


# ---------------------------------------------------------------- the subscriber (this process)


async def _receive(case: Case, robot: str) -> dict[str, Any]:
    from sage_robot.core.bus import Bus
    from sage_robot.core.clock import WallClock
    from sage_robot.core.realtime import describe, set_fifo, set_normal
    from sage_robot.core.transport.zenoh_bus import ZenohTransport

    port = _free_port()
    refused = set_fifo(case.receiver_fifo) if case.receiver_fifo else None
    receiver = describe()
    if refused:
        receiver += f" ({refused})"
    transport = ZenohTransport(settings_for(robot, [f"tcp/127.0.0.1:{port}"], []))
    zenoh_refused = _raise_zenoh_threads(case.zenoh_fifo)
    bus = Bus(WallClock(), transport)
    latencies: list[float] = []
    times: list[float] = []  # first and last arrival
    done = asyncio.Event()

    def on_msg(msg: Any) -> None:
        now = time.perf_counter()
        if _stamp(msg) == 0.0:  # the publisher's declaring message
            return
        times[1:] = [now]
        if len(times) == 1:
            times.insert(0, now)
        latencies.append(now - _stamp(msg))
        if len(latencies) >= case.messages:
            done.set()

    bus.subscribe(TOPIC, type(_message_maker(case.kind)(0.0)), on_msg, maxsize=case.messages)
    child = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "sage_robot.bench.bus_zenoh", "--child",
        robot, str(port), case.kind, str(case.messages), str(case.rate_hz or 0), str(case.zenoh_fifo),
    )
    try:
        await _until_received_or_exited(done, child)
    finally:
        try:
            await asyncio.wait_for(child.wait(), RECEIVE_TIMEOUT_S)
        except asyncio.TimeoutError:
            child.kill()
            await child.wait()
        transport.close()
        set_normal()
    publisher = _publisher(case.zenoh_fifo, zenoh_refused)
    return {**_summary(case, latencies, times), "receiver": receiver, "publisher": publisher}


def _raise_zenoh_threads(priority: int) -> str | None:
    """This process's Zenoh threads at ``priority`` as a group's are; why not, if refused."""
    from sage_robot.core.realtime import raise_threads
    from sage_robot.core.transport.keys import ZENOH_THREADS

    return raise_threads(priority, ZENOH_THREADS)[1] if priority else None


def _publisher(zenoh_fifo: int, refused: str | None) -> str:
    """The publisher as it ran: normal, its Zenoh threads at ``zenoh_fifo`` unless this
    process (same machine, same limits) was refused that."""
    if not zenoh_fifo:
        return "normal"
    if refused:
        return f"normal (Zenoh threads: {refused})"
    return f"normal, Zenoh threads SCHED_FIFO {zenoh_fifo}"


async def _until_received_or_exited(done: asyncio.Event, child: Any) -> None:
    """Until every message arrived, or the publisher exited and :data:`DRAIN_S` passed (the
    rest were lost), or the time is up."""
    waiters = {asyncio.ensure_future(done.wait()), asyncio.ensure_future(child.wait())}
    try:
        await asyncio.wait(waiters, timeout=RECEIVE_TIMEOUT_S + CHILD_START_S, return_when="FIRST_COMPLETED")
        if not done.is_set():
            with contextlib.suppress(asyncio.TimeoutError):
                await asyncio.wait_for(done.wait(), DRAIN_S)
    finally:
        for w in waiters:
            w.cancel()


def _summary(case: Case, latencies: list[float], times: list[float]) -> dict[str, Any]:
    lat = np.array(latencies or [float("nan")]) * 1e3
    received = len(latencies)
    t0, t1 = (times[0], times[-1]) if times else (0.0, 0.0)
    return {
        "message": case.label,
        "transport": "zenoh, two processes",
        "mode": f"paced {case.rate_hz:g} Hz" if case.rate_hz else "flood",
        "sent": case.messages,
        "received": received,
        "messages_per_s": round((received - 1) / (t1 - t0)) if received > 1 and t1 > t0 else None,
        "latency_p50_ms": round(float(np.percentile(lat, 50)), 3),
        "latency_p99_ms": round(float(np.percentile(lat, 99)), 3),
        "latency_max_ms": round(float(np.max(lat)), 3),
    }


def run_cases(cases: list[Case]) -> list[dict[str, Any]]:
    import uuid

    results = []
    for case in cases:
        robot = f"bench{uuid.uuid4().hex[:8]}"  # each case its own key prefix
        results.append(asyncio.run(_receive(case, robot)))
    return results


# ---------------------------------------------------------------- the publisher (the child)


async def _publish(
    robot: str, port: int, kind: str, messages: int, rate_hz: float, zenoh_fifo: int = 0
) -> None:
    from sage_robot.core.bus import Bus
    from sage_robot.core.clock import WallClock
    from sage_robot.core.transport.zenoh_bus import ZenohTransport

    transport = ZenohTransport(settings_for(robot, [], [f"tcp/127.0.0.1:{port}"]))
    refused = _raise_zenoh_threads(zenoh_fifo)
    if refused:
        print(f"bench publisher: Zenoh threads: {refused}", file=sys.stderr)
    bus = Bus(WallClock(), transport)
    make = _message_maker(kind)
    try:
        bus.publish(TOPIC, make(0.0))  # declares the publisher; the receiver skips stamp 0
        deadline = time.monotonic() + CHILD_START_S
        # A flag set on Zenoh's thread: polled (bounded), no event to await.
        while not transport.matched(TOPIC) and time.monotonic() < deadline:  # noqa: ASYNC110
            await asyncio.sleep(0.01)
        await asyncio.sleep(SETTLE_S)
        await _send(bus, make, messages, rate_hz)
        await asyncio.sleep(SETTLE_S)  # let the last frames leave before the session closes
    finally:
        transport.close()


async def _send(bus: Any, make: Any, messages: int, rate_hz: float) -> None:
    period = 1.0 / rate_hz if rate_hz > 0 else 0.0
    next_t = time.perf_counter()
    for i in range(messages):
        if period:
            next_t += period
            await asyncio.sleep(max(0.0, next_t - time.perf_counter()))
        elif i % BURST == BURST - 1:
            await asyncio.sleep(0)
        bus.publish(TOPIC, make(time.perf_counter()))


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument(
        "--child", nargs=6, metavar=("ROBOT", "PORT", "KIND", "N", "RATE", "ZENOH_FIFO"), required=True
    )
    robot, port, kind, n, rate, zenoh_fifo = p.parse_args(argv).child
    from sage_robot.core.realtime import set_normal

    set_normal()  # not the receiver's real-time priority, which a child inherits
    asyncio.run(_publish(robot, int(port), kind, int(n), float(rate), int(zenoh_fifo)))


if __name__ == "__main__":
    main()
