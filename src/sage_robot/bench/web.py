"""Web server: teleop command -> CMD frame on the serial port, status fan-out, video frames/s.

``teleop``: the real WebNode and SerialBridgeNode on a wall-clock bus; the bridge writes to
a pty (the MCU engineer's PtyMcu) whose master side is sniffed by a thread. A WebSocket
client (another thread, as a browser would be another process) sends
``{"type": "control"}`` messages on /ws/teleop; latency = CMD frame arrival - send.
The browser's own key-event handling (well under 1 ms) is not included.
``fanout``: N clients on /ws/status; ui_state messages published on the bus at 20 Hz;
latency = client receive - bus publish, and the share of messages delivered.
``video``: JPEG frames (640x360) published on the camera topic at 30 Hz; frames/s that
reach each of K /ws/camera clients (the per-client cap is web.camera_fps).
"""

from __future__ import annotations

import argparse
import asyncio
import io
import json
import os
import threading
import time
from typing import Any

import numpy as np

BENCH_PASSWORD_ENV = "SAGE_OPERATOR_PASSWORD"
FANOUT_RATE_HZ = 20.0  # ui_state publications per second in the fan-out case
VIDEO_RATE_HZ = 30.0  # camera frames published per second
VIDEO_SIZE = (640, 360)  # px
CONNECT_TIMEOUT_S = 10.0


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--commands", type=int, default=500, help="teleop control messages to time")
    p.add_argument("--clients", type=int, default=50, help="status WebSocket clients (fan-out)")
    p.add_argument("--messages", type=int, default=100, help="ui_state messages in the fan-out case")
    p.add_argument("--video-clients", type=int, default=5, help="camera WebSocket clients")
    p.add_argument("--video-s", type=float, default=5.0, help="seconds of video")
    p.add_argument("--camera-fps", type=float, default=15.0, help="web.camera_fps (per-client cap)")


def _pct(values: list[float], q: float) -> float:
    return round(float(np.percentile(np.array(values) * 1e3, q)), 3) if values else float("nan")


class _ClientThread:
    """An asyncio loop in a thread for the WebSocket clients."""

    def __init__(self) -> None:
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True, name="bench-clients")
        self.thread.start()

    async def await_(self, coro: Any, timeout: float) -> Any:
        fut = asyncio.run_coroutine_threadsafe(coro, self.loop)
        return await asyncio.wait_for(asyncio.wrap_future(fut), timeout)

    def close(self) -> None:
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(2.0)


async def _teleop_case(url: str, cookie: str, sniffer: Any, n: int, clients: _ClientThread) -> dict[str, Any]:
    from websockets.asyncio.client import connect

    from sage_robot.bench.mcu import CMD_STEP_MPS, CMD_WAIT_S

    async def drive() -> tuple[list[float], int]:
        latencies, lost = [], 0
        async with connect(url + "/ws/teleop", additional_headers={"Cookie": cookie}) as ws:
            for i in range(1, n + 1):
                key = i % 500 + 1  # x = key mm/s, within the profile's limits
                sniffer.arrivals.pop(key, None)
                t0 = time.perf_counter()
                await ws.send(json.dumps({"type": "control", "x": key * CMD_STEP_MPS, "z": 0.0}))
                while key not in sniffer.arrivals and time.perf_counter() - t0 < CMD_WAIT_S:
                    await asyncio.sleep(0.0002)
                if key in sniffer.arrivals:
                    latencies.append(sniffer.arrivals[key] - t0)
                else:
                    lost += 1
            await ws.send(json.dumps({"type": "control", "x": 0.0, "z": 0.0}))
        return latencies, lost

    latencies, lost = await clients.await_(drive(), timeout=n * 1.0 + 30)
    return {
        "commands": n,
        "lost": lost,
        "latency_p50_ms": _pct(latencies, 50),
        "latency_p99_ms": _pct(latencies, 99),
        "latency_max_ms": _pct(latencies, 100),
        "target_p99_ms": 20.0,
    }


async def _fanout_case(
    url: str, bus: Any, n_clients: int, n_msgs: int, clients: _ClientThread
) -> dict[str, Any]:
    from websockets.asyncio.client import connect

    from sage_robot.core import topics
    from sage_robot.core.msgs.voice import Phase, UiState

    received: list[dict[int, float]] = [{} for _ in range(n_clients)]
    ready, stop = threading.Event(), threading.Event()
    connected = [0]

    async def client(i: int) -> None:
        async with connect(url + "/ws/status", max_queue=None) as ws:
            connected[0] += 1
            if connected[0] == n_clients:
                ready.set()
            async for raw in ws:
                msg = json.loads(raw)
                if msg.get("type") == "ui_state" and msg["llm_tokens"].isdigit():
                    received[i][int(msg["llm_tokens"])] = time.perf_counter()

    async def all_clients() -> None:
        tasks = [asyncio.ensure_future(client(i)) for i in range(n_clients)]
        await asyncio.get_running_loop().run_in_executor(None, stop.wait)
        for t in tasks:
            t.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)

    fut = asyncio.run_coroutine_threadsafe(all_clients(), clients.loop)
    await asyncio.get_running_loop().run_in_executor(None, ready.wait, CONNECT_TIMEOUT_S)
    sent: dict[int, float] = {}
    period = 1.0 / FANOUT_RATE_HZ
    for seq in range(n_msgs):
        sent[seq] = time.perf_counter()
        bus.publish(topics.UI_STATE, UiState(Phase.SPEAKING, llm_tokens=str(seq)))
        await asyncio.sleep(period)
    await asyncio.sleep(0.5)
    stop.set()
    await asyncio.wrap_future(fut)
    lat = [r[s] - sent[s] for r in received for s in r if s in sent]
    delivered = sum(len(r) for r in received)
    return {
        "clients": n_clients,
        "connected": connected[0],
        "messages": n_msgs,
        "rate_hz": FANOUT_RATE_HZ,
        "delivered_fraction": round(delivered / (n_clients * n_msgs), 4),
        "latency_p50_ms": _pct(lat, 50),
        "latency_p99_ms": _pct(lat, 99),
    }


def _jpeg_frames(n: int) -> list[bytes]:
    from PIL import Image

    rng = np.random.default_rng(0)
    out = []
    base = np.tile(np.linspace(0, 255, VIDEO_SIZE[0], dtype=np.uint8), (VIDEO_SIZE[1], 1))
    for i in range(n):
        img = np.stack([base, np.roll(base, i * 7, axis=1), base[::-1]], axis=-1)
        img = (img + rng.integers(0, 24, img.shape, dtype=np.uint8)).astype(np.uint8)
        buf = io.BytesIO()
        Image.fromarray(img).save(buf, format="JPEG", quality=75)
        out.append(buf.getvalue())
    return out


async def _video_case(
    url: str, cookie: str, bus: Any, k: int, seconds: float, cap: float, clients: _ClientThread
) -> dict[str, Any]:
    from websockets.asyncio.client import connect

    from sage_robot.core import topics
    from sage_robot.core.msgs import CompressedImage

    frames = _jpeg_frames(30)
    counts = [0] * k
    nbytes = [0] * k
    ready = threading.Event()
    stop = threading.Event()
    connected = [0]

    async def client(i: int) -> None:
        async with connect(url + "/ws/camera", additional_headers={"Cookie": cookie}, max_size=None) as ws:
            connected[0] += 1
            if connected[0] == k:
                ready.set()
            async for raw in ws:
                if isinstance(raw, bytes) and not stop.is_set():
                    counts[i] += 1
                    nbytes[i] += len(raw)

    async def all_clients() -> None:
        tasks = [asyncio.ensure_future(client(i)) for i in range(k)]
        await asyncio.get_running_loop().run_in_executor(None, stop.wait)
        for t in tasks:
            t.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)

    fut = asyncio.run_coroutine_threadsafe(all_clients(), clients.loop)
    await asyncio.get_running_loop().run_in_executor(None, ready.wait, CONNECT_TIMEOUT_S)
    published = 0
    t0 = time.perf_counter()
    period = 1.0 / VIDEO_RATE_HZ
    while time.perf_counter() - t0 < seconds:
        frame = frames[published % len(frames)]
        bus.publish(topics.CAMERA, CompressedImage(time.time(), "camera", "jpeg", frame))
        published += 1
        await asyncio.sleep(max(0.0, t0 + published * period - time.perf_counter()))
    elapsed = time.perf_counter() - t0
    stop.set()
    await asyncio.wrap_future(fut)
    fps = [c / elapsed for c in counts]
    return {
        "clients": k,
        "published_fps": round(published / elapsed, 1),
        "cap_fps": cap,
        "frame_kb": round(float(np.mean([len(f) for f in frames])) / 1024, 1),
        "delivered_fps_min": round(min(fps), 1),
        "delivered_fps_mean": round(float(np.mean(fps)), 1),
        "mbytes_per_s_total": round(sum(nbytes) / elapsed / 1e6, 2),
    }


async def _main(args: argparse.Namespace) -> dict[str, Any]:
    import httpx

    from sage_robot.bench.mcu import _Sniffer
    from sage_robot.core.bus import Bus
    from sage_robot.core.clock import WallClock
    from sage_robot.core.config import load_profile
    from sage_robot.core.node import NodeContext
    from sage_robot.hardware.mcu.bridge import PORT_RESOURCE, SerialBridgeNode
    from sage_robot.sim.firmware import FirmwareModel
    from sage_robot.sim.mcu_pty import PtyMcu
    from sage_robot.web.node import WebNode

    password = os.environ.get(BENCH_PASSWORD_ENV) or "bench-" + os.urandom(6).hex()
    os.environ[BENCH_PASSWORD_ENV] = password
    clock = WallClock()
    settings = load_profile(None, {"web": {"host": "127.0.0.1", "port": 0, "camera_fps": args.camera_fps}})
    ctx = NodeContext(Bus(clock), clock, settings)
    pty = PtyMcu(FirmwareModel())
    ctx.resources[PORT_RESOURCE] = pty.port_name
    sniffer = _Sniffer(pty.master_fd)
    sniffer.start()
    bridge, web = SerialBridgeNode(ctx), WebNode(ctx)
    await bridge.setup()
    await web.setup()
    clients = _ClientThread()
    try:
        while not bridge.connected:
            await asyncio.sleep(0.01)
        async with httpx.AsyncClient(base_url=web.url) as http:
            resp = await http.post("/api/login", json={"password": password})
            resp.raise_for_status()
            cookie = f"sage_session={resp.cookies['sage_session']}"
        ws_url = web.url.replace("http://", "ws://")
        teleop = await _teleop_case(ws_url, cookie, sniffer, args.commands, clients)
        fanout = await _fanout_case(ws_url, ctx.bus, args.clients, args.messages, clients)
        video = await _video_case(
            ws_url, cookie, ctx.bus, args.video_clients, args.video_s, args.camera_fps, clients
        )
        return {"bench": "web", "teleop_to_cmd_frame": teleop, "status_fanout": fanout, "video": video}
    finally:
        clients.close()
        for node in (web, bridge):
            await node.teardown()
            await node._close()
        sniffer.stop.set()
        sniffer.join(1.0)
        pty.close()


def run(args: argparse.Namespace) -> dict[str, Any]:
    return asyncio.run(_main(args))
