"""RPLIDAR A1 driver: serial session (info, health, scan) and revolution → LaserScan.

Frames: the lidar measures clockwise from its own 0° mark; ROS and SAGE use counter-
clockwise angles, so a sample at ``a`` degrees lies at ``-a`` (rad) in the ``laser``
frame (the sllidar_ros2 convention with ``inverted: false``). The mount's yaw relative to
base_link is applied by whoever transforms the scan (the lidar pose in the profile).
"""

from __future__ import annotations

import contextlib
import math
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sage_robot.core.errors import DeviceNotConnectedError
from sage_robot.core.msgs import LaserScan
from sage_robot.hardware.rplidar import protocol as p

READ_TIMEOUT_S = 1.0
MOTOR_SPINUP_S = 0.0  # the A1 spins up while we wait for the first revolution anyway
RANGE_MIN_M = 0.15  # A1M8 datasheet
RANGE_MAX_M = 12.0
BINS = 360  # 1° bins for /scan
MIN_SAMPLES_PER_REV = 20  # fewer: a partial revolution at start-up, dropped


@dataclass
class LinkStats:
    revolutions: int = 0
    samples: int = 0
    resyncs: int = 0
    bad_descriptors: int = 0
    extra: dict[str, int] = field(default_factory=dict)


class RplidarDriver:
    """A blocking session with one lidar. Use from a thread (the node does)."""

    def __init__(self, port: str, baud: int = p.BAUD) -> None:
        self.port, self.baud = port, baud
        self._ser: Any = None  # serial.Serial once connected
        self.stats = LinkStats()

    # ------------------------------------------------------------ session
    def connect(self) -> None:
        import serial  # pyserial

        try:
            self._ser = serial.Serial(self.port, self.baud, timeout=READ_TIMEOUT_S)
        except (serial.SerialException, OSError) as exc:
            raise DeviceNotConnectedError(f"lidar: cannot open {self.port}: {exc}") from None
        self._motor(True)

    def _motor(self, on: bool) -> None:
        """A1 adapter: DTR low runs the motor. A pseudo-terminal has no modem lines."""
        with contextlib.suppress(OSError):
            self._ser.dtr = not on

    def disconnect(self) -> None:
        if self._ser is not None:
            try:
                self._ser.write(p.request(p.Command.STOP))
                self._motor(False)
                self._ser.close()
            except Exception:
                pass
            self._ser = None

    def __enter__(self) -> RplidarDriver:
        self.connect()
        return self

    def __exit__(self, *exc: object) -> None:
        self.disconnect()

    def _read(self, n: int) -> bytes:
        if self._ser is None:
            raise DeviceNotConnectedError("lidar: not connected")
        data = self._ser.read(n)
        if len(data) != n:
            raise DeviceNotConnectedError(f"lidar on {self.port} stopped answering ({len(data)}/{n} bytes)")
        return bytes(data)

    def _command(self, cmd: p.Command) -> p.ResponseSpec:
        assert self._ser is not None
        self._ser.reset_input_buffer()
        self._ser.write(p.request(cmd))
        spec = p.parse_descriptor(self._read(p.DESCRIPTOR_LEN))
        expected = p.RESPONSES[cmd]
        if spec != expected:
            self.stats.bad_descriptors += 1
            raise p.ProtocolError(f"lidar answered {cmd.name} with {spec}, expected {expected}")
        return spec

    def info(self) -> p.DeviceInfo:
        spec = self._command(p.Command.GET_INFO)
        return p.parse_info(self._read(spec.length))

    def health(self) -> tuple[str, int]:
        spec = self._command(p.Command.GET_HEALTH)
        return p.parse_health(self._read(spec.length))

    def stop(self) -> None:
        if self._ser is not None:
            self._ser.write(p.request(p.Command.STOP))
            time.sleep(0.002)  # the device needs 1 ms before the next request
            self._ser.reset_input_buffer()

    # ------------------------------------------------------------ scanning
    def revolutions(self) -> Iterator[list[p.Sample]]:
        """Start a scan and yield whole revolutions until the caller stops iterating."""
        self._command(p.Command.SCAN)
        current: list[p.Sample] = []
        buf = self._read(p.SAMPLE_LEN)
        while True:
            try:
                sample = p.parse_sample(buf)
            except p.ProtocolError:
                self.stats.resyncs += 1  # lost sync: slide one byte
                buf = buf[1:] + self._read(1)
                continue
            if sample.start and current:
                if len(current) >= MIN_SAMPLES_PER_REV:
                    self.stats.revolutions += 1
                    yield current
                current = []
            current.append(sample)
            self.stats.samples += 1
            buf = self._read(p.SAMPLE_LEN)


def revolution_to_scan(
    samples: list[p.Sample], stamp: float, scan_time: float, frame_id: str = "laser"
) -> LaserScan:
    """Bin a revolution into 1° beams, counter-clockwise from -π; inf where nothing returned."""
    ranges = np.full(BINS, np.inf, dtype=np.float32)
    inc = 2.0 * math.pi / BINS
    for s in samples:
        dist = s.distance_mm / 1000.0
        if s.distance_mm <= 0 or not RANGE_MIN_M <= dist <= RANGE_MAX_M:
            continue
        angle = (-math.radians(s.angle_deg) + math.pi) % (2.0 * math.pi) - math.pi
        i = round((angle + math.pi) / inc) % BINS  # beam i is at -π + i·inc
        ranges[i] = min(ranges[i], dist)
    return LaserScan(stamp, frame_id, -math.pi, inc, RANGE_MIN_M, RANGE_MAX_M, ranges, scan_time)
