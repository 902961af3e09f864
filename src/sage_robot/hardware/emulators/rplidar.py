"""An RPLIDAR A1 on a pseudo-terminal: answers info/health/scan/stop like the device.

``ranges_fn(angles_deg) -> distances_m`` gives what the lidar sees (a fixed room by default).
"""

from __future__ import annotations

import contextlib
import math
import os
import select
import threading
import time
import tty
from collections.abc import Callable

import numpy as np

from sage_robot.hardware.rplidar import protocol as p

SAMPLES_PER_REV = 360
REV_HZ = 5.5  # A1M8 legacy scan mode: ~2000 samples/s at 5.5 Hz


def square_room(half_size_m: float = 3.0) -> Callable[[np.ndarray], np.ndarray]:
    """Distances from the centre of a square room to its walls (clockwise degrees)."""

    def ranges(angles_deg: np.ndarray) -> np.ndarray:
        a = np.radians(angles_deg)
        c, s = np.abs(np.cos(a)), np.abs(np.sin(a))
        dist: np.ndarray = half_size_m / np.maximum(np.maximum(c, s), 1e-9)
        return dist

    return ranges


class RplidarEmulator:
    def __init__(
        self,
        ranges_fn: Callable[[np.ndarray], np.ndarray] | None = None,
        info: p.DeviceInfo | None = None,
        health: tuple[int, int] = (0, 0),
        samples_per_rev: int = SAMPLES_PER_REV,
        rev_hz: float = REV_HZ,
    ) -> None:
        self.ranges_fn = ranges_fn or square_room()
        self.info = info or p.DeviceInfo(0x18, (1, 29), 7, "0123456789ABCDEF0123456789ABCDEF")
        self.health = health
        self.samples_per_rev, self.rev_hz = samples_per_rev, rev_hz
        self.master, slave = os.openpty()
        tty.setraw(slave)
        self.port_name = os.ttyname(slave)
        self._slave = slave
        self._scanning = False
        self._stop = threading.Event()
        self.commands: list[str] = []
        self._thread = threading.Thread(target=self._serve, name="rplidar-emulator", daemon=True)
        self._thread.start()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2)
        for fd in (self.master, self._slave):
            with contextlib.suppress(OSError):
                os.close(fd)

    def _write(self, data: bytes) -> None:
        try:
            os.write(self.master, data)
        except OSError:
            self._stop.set()

    def _handle(self, cmd: int) -> None:
        try:
            command = p.Command(cmd)
        except ValueError:
            return  # the real device ignores unknown requests
        self.commands.append(command.name)
        if command is p.Command.STOP or command is p.Command.RESET:
            self._scanning = False
        elif command is p.Command.GET_INFO:
            self._write(p.descriptor(p.RESPONSES[command]) + p.encode_info(self.info))
        elif command is p.Command.GET_HEALTH:
            self._write(p.descriptor(p.RESPONSES[command]) + p.encode_health(*self.health))
        elif command in (p.Command.SCAN, p.Command.FORCE_SCAN):
            self._write(p.descriptor(p.RESPONSES[command]))
            self._scanning = True

    def _revolution(self) -> bytes:
        angles = np.arange(self.samples_per_rev) * (360.0 / self.samples_per_rev)
        dists = np.asarray(self.ranges_fn(angles), dtype=np.float64)
        out = bytearray()
        for i, (a, d) in enumerate(zip(angles, dists, strict=True)):
            mm = 0.0 if not math.isfinite(d) or d > 12.0 else d * 1000.0
            out += p.encode_sample(p.Sample(i == 0, 47 if mm else 0, float(a), mm))
        return bytes(out)

    def _serve(self) -> None:
        pending = bytearray()
        next_rev = time.monotonic()
        while not self._stop.is_set():
            timeout = max(0.0, next_rev - time.monotonic()) if self._scanning else 0.05
            try:
                ready, _, _ = select.select([self.master], [], [], timeout)
            except (OSError, ValueError):
                return
            if ready:
                try:
                    pending += os.read(self.master, 256)
                except OSError:
                    return
                while len(pending) >= 2:
                    if pending[0] != p.SYNC_REQUEST:
                        del pending[0]
                        continue
                    self._handle(pending[1])
                    del pending[:2]
            if self._scanning and time.monotonic() >= next_rev:
                self._write(self._revolution())
                next_rev = time.monotonic() + 1.0 / self.rev_hz
