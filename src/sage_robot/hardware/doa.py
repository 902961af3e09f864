"""Direction of arrival from the XMOS XVF3800 mic array (USB vendor control transfer).

The seed's ``doa_server.py`` reads the AEC azimuths: resource 33, command 75
(``AEC_AZIMUTH_VALUES``), four little-endian float32 radians after one status byte
(beam 1, beam 2, free-running beam, auto-selected beam). We use the auto-selected beam.

Angle convention (the seed's): 0° behind the robot, 90° left, 180° front, 270° right.
``offset_deg`` turns the device's frame into that one (it depends on the mounting).
Without the device (or without pyusb) :meth:`XVF3800Doa.open` raises
:class:`DeviceNotConnectedError`; the caller falls back to a fixed or simulated angle.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from typing import Any

from sage_robot.core.errors import DeviceNotConnectedError

USB_VID = 0x2886  # Seeed reSpeaker XVF3800 4-mic array
USB_PID = 0x001A
CTRL_IN_VENDOR_DEVICE = 0x80 | 0x40 | 0x00  # device-to-host | vendor | recipient device
READ_FLAG = 0x80  # wValue = READ_FLAG | command id for reads
STATUS_OK = 0
STATUS_RETRY = 64  # the chip was busy: ask again
TIMEOUT_MS = 100  # one control transfer (ms)
FRONT_DEG = 180.0  # seed convention: straight ahead


@dataclass(frozen=True)
class Parameter:
    """One entry of the chip's control map: resource id, command id, value format."""

    resid: int
    cmdid: int
    fmt: str  # struct format of the payload (little-endian)

    @property
    def length(self) -> int:
        return 1 + struct.calcsize(self.fmt)  # status byte + payload


# The control map, as data (the encoder and decoder both read it).
PARAMETERS = {
    "AEC_AZIMUTH_VALUES": Parameter(33, 75, "<4f"),  # radians: beam1, beam2, free, auto
    "AEC_SPENERGY_VALUES": Parameter(33, 80, "<4f"),  # speech energy per beam
    "DOA_VALUE": Parameter(20, 18, "<2H"),  # degrees, speech flag (coarse, LED ring)
}
AUTO_BEAM = 3  # index of the auto-selected beam in AEC_AZIMUTH_VALUES


class DoaReadError(DeviceNotConnectedError):
    """The device answered with an error status or a short reply."""


def decode(param: Parameter, reply: bytes) -> tuple[float, ...]:
    """A control reply (status byte + payload) → values; raises on a bad status."""
    if len(reply) < param.length:
        raise DoaReadError(f"short reply: {len(reply)} bytes, expected {param.length}")
    status = reply[0]
    if status == STATUS_RETRY:
        raise DoaReadError("device busy (retry)")
    if status != STATUS_OK:
        raise DoaReadError(f"device error status {status}")
    return tuple(struct.unpack(param.fmt, bytes(reply[1 : param.length])))


def azimuth_to_seed_deg(azimuth_rad: float, offset_deg: float = 0.0) -> float:
    """Device azimuth (rad) → seed convention degrees in [0, 360)."""
    return (math.degrees(azimuth_rad) + offset_deg) % 360.0


class XVF3800Doa:
    """Reads the speaker azimuth from the XVF3800 over USB (pyusb)."""

    source = "xvf3800"

    def __init__(self, offset_deg: float = 0.0, vid: int = USB_VID, pid: int = USB_PID) -> None:
        self.offset_deg, self.vid, self.pid = offset_deg, vid, pid
        self._dev: Any = None  # the usb.core device, once open
        self.last_deg = FRONT_DEG

    def open(self) -> None:
        try:
            import usb.core
        except ImportError:
            raise DeviceNotConnectedError("pyusb is not installed (pip install pyusb)") from None
        try:
            dev = usb.core.find(idVendor=self.vid, idProduct=self.pid)
        except Exception as exc:  # usb.core.NoBackendError when libusb is missing
            raise DeviceNotConnectedError(f"USB unavailable: {exc}") from None
        if dev is None:
            raise DeviceNotConnectedError(
                f"XVF3800 mic array (USB {self.vid:04x}:{self.pid:04x}) not found"
            )
        self._dev = dev

    @property
    def is_connected(self) -> bool:
        return self._dev is not None

    def read_param(self, name: str) -> tuple[float, ...]:
        if self._dev is None:
            raise DeviceNotConnectedError("XVF3800 is not open")
        p = PARAMETERS[name]
        try:
            reply = self._dev.ctrl_transfer(
                CTRL_IN_VENDOR_DEVICE, 0, READ_FLAG | p.cmdid, p.resid, p.length, TIMEOUT_MS
            )
        except Exception as exc:  # usb.core.USBError: unplugged, timeout
            self._dev = None
            raise DeviceNotConnectedError(f"XVF3800 read failed: {exc}") from None
        return decode(p, bytes(reply))

    def read_deg(self) -> float:
        """Speaker direction (seed convention); the last good value when the chip is busy."""
        try:
            values = self.read_param("AEC_AZIMUTH_VALUES")
        except DoaReadError:
            return self.last_deg
        az = values[AUTO_BEAM]
        if math.isfinite(az):
            self.last_deg = azimuth_to_seed_deg(az, self.offset_deg)
        return self.last_deg

    def close(self) -> None:
        if self._dev is not None:
            try:
                import usb.util

                usb.util.dispose_resources(self._dev)
            except Exception:  # closing a device that is gone
                pass
        self._dev = None
