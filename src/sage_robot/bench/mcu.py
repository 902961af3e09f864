"""MCU link: decoder throughput and /cmd_vel -> bytes-on-the-wire latency over a pty.

``decoder``: a wire-like mix of frames (IMU : ODOM : BATTERY = 2 : 1 : 1, as at 100/50/50
Hz) fed in 64-byte chunks (a USB full-speed CDC packet) and in 4 KiB chunks.
``cmd_latency``: the real SerialBridgeNode on a wall-clock bus writes to a pty; a thread on
the master side timestamps each new CMD frame's arrival; latency = arrival - publish.
``dialects``: per firmware dialect, commands applied / sent, wild commands, /cmd_vel silence
and kill -9 to a stop on the wire (:mod:`sage_robot.bench.mcu_dialects`).
"""

from __future__ import annotations

import argparse
import asyncio
import os
import select
import threading
import time
from typing import Any

import numpy as np

USB_PACKET_BYTES = 64
BIG_CHUNK_BYTES = 4096
CMD_STEP_MPS = 1e-3  # successive commands differ by this, so each is recognisable
CMD_WAIT_S = 1.0  # give up on one command after this (counted as lost)


def add_arguments(p: argparse.ArgumentParser) -> None:
    from sage_robot.bench import mcu_dialects

    p.add_argument("--frames", type=int, default=200_000, help="frames for the decoder case")
    p.add_argument("--commands", type=int, default=500, help="/cmd_vel messages for latency")
    mcu_dialects.add_arguments(p)


def _decoder_case(n_frames: int, chunk: int) -> dict[str, Any]:
    from sage_robot.hardware.mcu import protocol as proto

    rng = np.random.default_rng(0)
    kinds = [proto.IMU, proto.ODOM, proto.BATTERY, proto.IMU]
    frames = []
    for i in range(n_frames):
        kind = kinds[i % len(kinds)]
        values = tuple(float(x) for x in rng.uniform(0.0, 3.0, len(kind.fields)))
        frames.append(proto.encode(kind, values))
    stream = b"".join(frames)
    chunks = [stream[i : i + chunk] for i in range(0, len(stream), chunk)]
    decoder = proto.Decoder()
    t0 = time.perf_counter()
    decoded = sum(len(decoder.feed(c)) for c in chunks)
    elapsed = time.perf_counter() - t0
    assert decoded == n_frames, f"decoded {decoded} of {n_frames}"
    return {
        "chunk_bytes": chunk,
        "frames_per_s": round(n_frames / elapsed),
        "mbytes_per_s": round(len(stream) / elapsed / 1e6, 2),
    }


class _Sniffer(threading.Thread):
    """Reads the pty master and records when each new CMD value first arrives."""

    def __init__(self, fd: int) -> None:
        super().__init__(daemon=True, name="bench-sniffer")
        from sage_robot.hardware.mcu import protocol as proto

        self.fd = fd
        self.decoder = proto.Decoder(accept=frozenset({proto.CMD.code}))
        self.arrivals: dict[int, float] = {}  # round(v / CMD_STEP_MPS) -> perf_counter
        self.stop = threading.Event()

    def run(self) -> None:
        while not self.stop.is_set():
            ready, _, _ = select.select([self.fd], [], [], 0.05)
            if not ready:
                continue
            try:
                data = os.read(self.fd, 4096)
            except BlockingIOError:
                continue
            now = time.perf_counter()
            for frame in self.decoder.feed(data):
                self.arrivals.setdefault(round(frame.values[0] / CMD_STEP_MPS), now)


async def _latency_case(n: int) -> dict[str, Any]:
    from sage_robot.core import topics
    from sage_robot.core.bus import Bus
    from sage_robot.core.clock import WallClock
    from sage_robot.core.config import load_profile
    from sage_robot.core.msgs import Twist
    from sage_robot.core.node import NodeContext
    from sage_robot.hardware.mcu.bridge import PORT_RESOURCE, SerialBridgeNode
    from sage_robot.sim.firmware import FirmwareModel
    from sage_robot.sim.mcu_pty import PtyMcu

    clock = WallClock()
    ctx = NodeContext(Bus(clock), clock, load_profile())
    pty = PtyMcu(FirmwareModel())
    ctx.resources[PORT_RESOURCE] = pty.port_name
    sniffer = _Sniffer(pty.master_fd)
    sniffer.start()
    bridge = SerialBridgeNode(ctx)
    await bridge.setup()
    try:
        while not bridge.connected:
            await asyncio.sleep(0.01)
        latencies, lost = [], 0
        for i in range(1, n + 1):
            key = i % 500 + 1  # v = key * 1 mm/s, within the profile's 0.8 m/s
            sniffer.arrivals.pop(key, None)
            t0 = time.perf_counter()
            ctx.bus.publish(topics.CMD_VEL, Twist(key * CMD_STEP_MPS, 0.0))
            while key not in sniffer.arrivals and time.perf_counter() - t0 < CMD_WAIT_S:
                await asyncio.sleep(0.0002)
            if key in sniffer.arrivals:
                latencies.append(sniffer.arrivals[key] - t0)
            else:
                lost += 1
        lat = np.array(latencies) * 1e6
        return {
            "commands": n,
            "lost": lost,
            "latency_p50_us": round(float(np.percentile(lat, 50)), 1),
            "latency_p99_us": round(float(np.percentile(lat, 99)), 1),
        }
    finally:
        await bridge._close()
        await bridge.teardown()
        sniffer.stop.set()
        sniffer.join(1.0)
        pty.close()


def run(args: argparse.Namespace) -> dict[str, Any]:
    decoder = [_decoder_case(args.frames, c) for c in (USB_PACKET_BYTES, BIG_CHUNK_BYTES)]
    from sage_robot.bench.mcu_dialects import run_dialects

    latency = asyncio.run(_latency_case(args.commands))
    dialects = asyncio.run(run_dialects(args))
    return {"bench": "mcu", "decoder": decoder, "cmd_latency": latency, "dialects": dialects}
