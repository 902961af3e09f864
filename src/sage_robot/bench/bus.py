"""Bus throughput and publish→callback latency, small and LaserScan-sized messages; in one
process, and between two processes over Zenoh (:mod:`sage_robot.bench.bus_zenoh`).

Heavy packages are imported inside ``run`` in every bench module, so `sage --help`
stays fast.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import time
from typing import Any

import numpy as np

SCAN_BEAMS = 360  # a LaserScan like the RPLIDAR A1's
IN_PROCESS_MESSAGES = 20000  # the in-process case with the Zenoh transport attached


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--messages", type=int, default=20000, help="messages per case")
    p.add_argument("--no-zenoh", action="store_true", help="only the in-process cases")
    p.add_argument(
        "--zenoh-scale", type=float, default=1.0, help="scale the Zenoh cases' message counts (e.g. 0.2)"
    )
    p.add_argument("--receiver-fifo", type=int, default=None, metavar="PRIORITY",
                   help="SCHED_FIFO priority of the paced /cmd_vel case's receiver, 0: normal "
                        "(default: the motion group's processes.realtime)")
    p.add_argument("--zenoh-fifo", type=int, default=None, metavar="PRIORITY",
                   help="SCHED_FIFO priority of both processes' Zenoh threads, 0: normal "
                        "(default: processes.zenoh_realtime, as the robot's groups have them)")
    p.add_argument("--at-rest", action="store_true",
                   help="also the CPU of `sage sim` at rest, one process vs process groups (minutes)")
    p.add_argument("--rest-warm", type=float, default=50.0, help="--at-rest: warm-up per mode (s)")
    p.add_argument("--rest-window", type=float, default=60.0, help="--at-rest: measured window per mode (s)")


async def _case(make: Any, n_subs: int, n_msgs: int, transport: Any = None) -> dict[str, float]:
    from sage_robot.core.bus import Bus

    bus = Bus(transport=transport)
    latencies: list[float] = []
    done = asyncio.Event()
    received = 0
    total = n_msgs * n_subs

    def on_msg(msg: Any) -> None:
        nonlocal received
        latencies.append(time.perf_counter() - msg.stamp)
        received += 1
        if received >= total:
            done.set()

    for _ in range(n_subs):
        bus.subscribe("/bench", type(make(0.0)), on_msg, maxsize=n_msgs)
    t0 = time.perf_counter()
    # Publish in bursts so subscribers run between them (like a 1 kHz producer at full speed).
    for i in range(n_msgs):
        bus.publish("/bench", make(time.perf_counter()))
        if i % 10 == 9:
            await asyncio.sleep(0)
    await asyncio.wait_for(done.wait(), 60)
    elapsed = time.perf_counter() - t0
    lat = np.array(latencies) * 1e6
    return {
        "subscribers": n_subs,
        "messages_per_s": round(total / elapsed),
        "latency_p50_us": round(float(np.percentile(lat, 50)), 1),
        "latency_p99_us": round(float(np.percentile(lat, 99)), 1),
    }


def run(args: argparse.Namespace) -> dict[str, Any]:
    from dataclasses import replace

    from sage_robot.core.msgs import LaserScan, Twist

    scan_template = LaserScan(
        0.0, "laser", -np.pi, np.pi / 180, 0.15, 12.0, np.ones(SCAN_BEAMS, dtype=np.float32)
    )

    def small(t: float) -> Any:
        return _Stamped(t, Twist(0.3, 0.1))

    def scan(t: float) -> Any:
        return replace(scan_template, stamp=t)

    cases = []
    for label, make in (("small", small), ("laserscan", scan)):
        for n_subs in (1, 10):
            result = asyncio.run(_case(make, n_subs, args.messages))
            cases.append({"message": label, **result})
    out: dict[str, Any] = {"bench": "bus", "cases": cases}
    if not args.no_zenoh:
        out["zenoh_cases"] = _zenoh_cases(
            args.zenoh_scale, _motion_fifo(args.receiver_fifo), _zenoh_fifo(args.zenoh_fifo)
        )
        # latency between processes is the machine's scheduling as much as the bus's: say how busy
        out["load_avg_1m"] = round(os.getloadavg()[0], 2)
    if args.at_rest:
        from sage_robot.bench.bus_rest import run_at_rest

        out["at_rest"] = run_at_rest(args.rest_warm, args.rest_window)
    return out


def _motion_fifo(asked: int | None) -> int:
    """The paced /cmd_vel receiver's real-time priority: as asked, or the motion group's."""
    if asked is not None:
        return asked
    from sage_robot.core.config.processes import ProcessSettings

    return ProcessSettings().realtime.get("motion", 0)


def _zenoh_fifo(asked: int | None) -> int:
    """Both processes' Zenoh threads' real-time priority: as asked, or the groups'."""
    if asked is not None:
        return asked
    from sage_robot.core.config.processes import ProcessSettings

    return ProcessSettings().zenoh_realtime


def _zenoh_cases(scale: float, motion_fifo: int = 0, zenoh_fifo: int = 0) -> list[dict[str, Any]] | str:
    if scale <= 0:
        from sage_robot.core.errors import SageError

        raise SageError(f"--zenoh-scale must be > 0, got {scale:g}")
    try:
        from sage_robot.bench.bus_zenoh import default_cases, run_cases, settings_for
        from sage_robot.core.transport.zenoh_bus import ZenohTransport
    except ImportError as exc:
        return f"skipped: {exc} (pip install 'sage-robot[zenoh]')"
    from sage_robot.core.msgs import Twist

    # In-process delivery with the Zenoh transport attached and no remote subscriber: what
    # every node pays once `bus.transport: zenoh` is on.
    transport = ZenohTransport(settings_for("benchlocal", [], []))
    n_msgs = max(10, int(IN_PROCESS_MESSAGES * scale))
    try:
        local = asyncio.run(_case(lambda t: _Stamped(t, Twist(0.3, 0.1)), 1, n_msgs, transport))
    finally:
        transport.close()
    in_process = {"message": "small", "transport": "zenoh attached, in-process subscriber", **local}
    return [in_process, *run_cases(default_cases(scale, motion_fifo, zenoh_fifo))]


class _Stamped:
    """A small message with a stamp (Twist has none)."""

    __slots__ = ("payload", "stamp")

    def __init__(self, stamp: float, payload: Any) -> None:
        self.stamp, self.payload = stamp, payload
