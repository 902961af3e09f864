"""The ``lidar`` node: RPLIDAR A1 → ``/scan`` at the device's rate, reconnecting by itself."""

from __future__ import annotations

import asyncio
import contextlib
import threading
from typing import Any

from sage_robot.core import topics
from sage_robot.core.bus import Topic
from sage_robot.core.errors import DeviceNotConnectedError
from sage_robot.core.msgs import DiagnosticStatus, Level
from sage_robot.core.node import Node
from sage_robot.hardware.rplidar.driver import RplidarDriver, revolution_to_scan
from sage_robot.hardware.rplidar.protocol import ProtocolError

LIDAR_STATUS = Topic("/lidar/status", DiagnosticStatus)  # connected or not, and why


class LidarNode(Node):
    name = "lidar"

    async def setup(self) -> None:
        self._stop = threading.Event()
        self.connected = False
        self.device = ""
        self.driver: RplidarDriver | None = None
        self._loop = asyncio.get_running_loop()
        self._rx_ended = asyncio.Event()  # set (from the thread) when the RX thread ends
        self._thread = self.start_thread(self._rx_then_signal, "lidar-rx")
        self.spawn(self._watch_thread())

    async def _watch_thread(self) -> None:
        await self._rx_ended.wait()

    def _rx_then_signal(self) -> None:
        try:
            self._rx()
        finally:
            with contextlib.suppress(RuntimeError):  # the event loop already closed (shutdown)
                self._loop.call_soon_threadsafe(self._rx_ended.set)

    def _status(self, level: Level, message: str) -> None:
        self.bus.publish_threadsafe(
            LIDAR_STATUS, DiagnosticStatus("lidar", level, message, {"port": self.settings.lidar.port})
        )

    def _rx(self) -> None:
        cfg = self.settings.lidar
        warned = False
        while not self._stop.is_set():
            driver = RplidarDriver(cfg.port, cfg.baud)
            try:
                driver.connect()
                info = driver.info()
                health, code = driver.health()
                self.device = (
                    f"model {info.model:#x} fw {info.firmware[0]}.{info.firmware[1]} sn {info.serial}"
                )
                if health == "error":
                    raise DeviceNotConnectedError(
                        f"lidar reports a hardware error (code {code}); power-cycle it"
                    )
                self.driver, self.connected, warned = driver, True, False
                self.log.info("lidar connected", port=cfg.port, device=self.device, health=health)
                self._status(Level.OK, f"scanning ({health})")
                last = self.clock.now()
                for rev in driver.revolutions():
                    if self._stop.is_set():
                        break
                    now = self.clock.now()
                    scan = revolution_to_scan(rev, now, max(now - last, 1e-3))
                    last = now
                    self.bus.publish_threadsafe(topics.SCAN, scan)
            except Exception as exc:  # the port vanished, garbage, or closed under us at shutdown
                if self._stop.is_set():
                    return
                if not isinstance(exc, (DeviceNotConnectedError, ProtocolError, OSError)):
                    self.log.warning("lidar read failed", error=f"{type(exc).__name__}: {exc}")
                self.connected = False
                if not warned:
                    self.log.warning("lidar unavailable, retrying", port=cfg.port, error=str(exc))
                    warned = True
                self._status(Level.ERROR, str(exc))
            finally:
                driver.disconnect()
            self._stop.wait(cfg.reconnect_s)

    async def teardown(self) -> None:
        self._stop.set()
        if self.driver is not None:
            self.driver.disconnect()
        await asyncio.to_thread(self._thread.join, 3.0)

    def stats(self) -> dict[str, Any]:
        s = self.driver.stats if self.driver else None
        return {
            "connected": self.connected,
            "device": self.device,
            "revolutions": s.revolutions if s else 0,
            "resyncs": s.resyncs if s else 0,
        }
