"""Finding and opening the MCU's serial port (USB CDC, /dev/ttyACM* on the Jetson)."""

from __future__ import annotations

import glob
import os
from typing import Any

from sage_robot.core.errors import DeviceNotConnectedError

AUTO = "auto"
AUTO_PATTERN = "/dev/ttyACM*"  # the STM32's USB CDC device
READ_TIMEOUT_S = 0.05  # RX thread wakes at least this often (to notice a stop request)
WRITE_TIMEOUT_S = 0.2  # a stuck port must not stall the event loop longer than this
HEARTBEAT_FD_ENV = "SAGE_HEARTBEAT_FD"  # set by the supervisor (app.supervisor): a pipe to beat on
HEARTBEAT_PERIOD_S = 0.05  # the bridge beats this often; the supervisor waits 0.2 s (s)


def heartbeat_fd() -> int | None:
    """In a process run by the supervisor: the pipe to write heartbeats to, else None."""
    raw = os.environ.get(HEARTBEAT_FD_ENV, "")
    return int(raw) if raw.isdigit() else None


def find_port(configured: str, pattern: str = AUTO_PATTERN) -> str:
    """The port to open: ``configured`` itself, or with 'auto' the first ``pattern`` match.

    Raises DeviceNotConnectedError naming what was looked for.
    """
    if configured and configured != AUTO:
        return configured
    found = sorted(glob.glob(pattern))
    if not found:
        raise DeviceNotConnectedError(
            f"no MCU serial port found ({pattern}); is the STM32 plugged in? "
            "Set mcu.port in the profile or pass --port"
        )
    return found[0]


def open_port(path: str, baud: int) -> Any:
    """Open ``path`` at ``baud`` (8N1, raw) with pyserial; DeviceNotConnectedError if it fails."""
    try:
        import serial
    except ImportError:
        raise DeviceNotConnectedError("pyserial is not installed: pip install 'sage-robot[mcu]'") from None
    try:
        port = serial.Serial(
            path, baud, timeout=READ_TIMEOUT_S, write_timeout=WRITE_TIMEOUT_S, exclusive=True
        )
        port.reset_input_buffer()  # stale frames queued while nobody listened
        return port
    except (serial.SerialException, OSError, ValueError) as exc:
        raise DeviceNotConnectedError(f"cannot open MCU port {path}: {exc}") from None
