"""The STM32 firmware dialects: how a command is written, and what the firmware does with it.

Both dialects send telemetry the same way (``0x7E TYPE LEN`` + float32 payload, read by
:class:`sage_robot.hardware.mcu.protocol.Decoder`); they differ in the command direction
and in what the firmware does on its own (docs/mcu.md has them side by side):

- ``documented`` — the seed document's framed command ``0x7E 0x01 0x08 v w``; the
  firmware hunts byte by byte for the header, stops the motors 550 ms after the last
  frame (watchdog) and reports the battery.
- ``seed-2025`` — what the seed robot's firmware does today: a 9-byte command ``0x78 v w``
  received in **fixed 9-byte blocks** (a block that does not start with ``0x78`` is dropped
  whole; a lost or extra byte misaligns it), applied with no range check, **no watchdog**,
  no BATTERY frames, a ``WHO_AM_I=0x71`` banner at boot, theta in (-2 pi, 2 pi).

For ``seed-2025`` the command writer guarantees that a misaligned firmware can never read
a header inside a payload: no payload byte is ever ``0x78`` (a float whose bytes hold one
is moved toward zero to the nearest float without it: by its last bit when the low byte
holds it, at most 0.8 % when a higher byte does). A stop is written as a
*stop burst*: nine copies of the stop command each followed by one filler byte. Whatever
the firmware's alignment, exactly one copy starts a block, so the stop is applied; and the
burst is ten blocks long, so the alignment afterwards is what it was before. One filler
byte written on its own shifts the alignment by one: the bridge's realignment step.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Literal

from sage_robot.core.errors import ConfigError
from sage_robot.hardware.mcu import protocol as proto

SEED_CMD_HEADER = 0x78  # 'x': the seed-2025 command's first byte
SEED_CMD_LEN = 9  # header + two float32
SEED_BLOCK = SEED_CMD_LEN  # the firmware receives fixed blocks of this many bytes
FILLER = b"\x00"  # never a header of either dialect
BANNER_PREFIX = b"WHO_AM_I="  # the seed-2025 firmware's boot line: WHO_AM_I=0x71\r\n
_PAIR = struct.Struct("<ff")

DialectName = Literal["seed-2025", "documented"]


def _without_header_byte(value: float) -> float:
    """``value`` as float32 moved toward zero to the nearest float none of whose 4 bytes is
    the seed-2025 header (0x78): where a byte is 0x78 it becomes 0x77 and every byte below
    it 0xFF. A low byte costs one last-bit step; the mantissa's top byte at most 0.8 %."""
    raw = bytearray(struct.pack("<f", value))
    for k in range(3, -1, -1):  # the most significant first: the lower bytes are then 0xFF
        if raw[k] == SEED_CMD_HEADER:
            raw[k] = SEED_CMD_HEADER - 1
            raw[:k] = b"\xff" * k
    return float(struct.unpack("<f", bytes(raw))[0])


@dataclass(frozen=True)
class Dialect:
    """What the bridge and the tools need to know about one firmware."""

    name: DialectName
    has_watchdog: bool  # the firmware stops by itself when commands stop
    has_battery: bool  # the firmware reports the pack voltage
    block_aligned: bool  # commands are received in fixed blocks (can misalign)
    description: str

    def command(self, v: float, w: float) -> bytes:
        """The bytes of one velocity command (finite v m/s, w rad/s)."""
        if self.name == "documented":
            return proto.encode(proto.CMD, (v, w))
        return bytes((SEED_CMD_HEADER,)) + _PAIR.pack(_without_header_byte(v), _without_header_byte(w))

    def command_values(self, data: bytes) -> tuple[float, float]:
        """The (v, w) a command's bytes carry (tests, tools)."""
        offset = proto.HEADER_LEN if self.name == "documented" else 1
        v, w = _PAIR.unpack_from(data, offset)
        return float(v), float(w)

    def stop(self) -> bytes:
        """Bytes that stop the robot whatever the firmware's alignment (see the module doc)."""
        frame = self.command(0.0, 0.0)
        if not self.block_aligned:
            return frame
        return (frame + FILLER) * SEED_BLOCK

    def realign_step(self) -> bytes:
        """Bytes that shift a block-aligned firmware's alignment by one (nothing otherwise)."""
        return FILLER if self.block_aligned else b""


DOCUMENTED = Dialect(
    "documented", has_watchdog=True, has_battery=True, block_aligned=False,
    description="the seed document's framed protocol (0x7E command, 550 ms watchdog, BATTERY frames)",
)
SEED_2025 = Dialect(
    "seed-2025", has_watchdog=False, has_battery=False, block_aligned=True,
    description="the seed robot's current firmware (9-byte 0x78 commands in fixed blocks, "
    "no watchdog, no battery frames, WHO_AM_I banner)",
)
DIALECTS: dict[str, Dialect] = {d.name: d for d in (SEED_2025, DOCUMENTED)}


def dialect(name: str) -> Dialect:
    found = DIALECTS.get(name)
    if found is None:
        raise ConfigError(f"mcu.firmware: unknown dialect {name!r}; known: {', '.join(DIALECTS)}")
    return found


class BannerWatch:
    """Finds the seed-2025 boot banner in the raw byte stream (any chunking)."""

    KEEP = 64  # bytes of the stream kept to find a banner split across reads

    def __init__(self) -> None:
        self._tail = b""
        self.banners = 0
        self.last = ""  # the last banner line seen, e.g. "WHO_AM_I=0x71"

    def feed(self, data: bytes) -> bool:
        """True when ``data`` completed a banner line."""
        buf = self._tail + data
        found = False
        start = buf.find(BANNER_PREFIX)
        while start >= 0:
            end = buf.find(b"\n", start)
            if end < 0:
                break
            self.last = buf[start:end].decode("ascii", "replace").strip()
            self.banners += 1
            found = True
            buf = buf[end + 1:]
            start = buf.find(BANNER_PREFIX)
        self._tail = buf[-self.KEEP:]
        return found


def guess(frames: dict[str, int], banners: int) -> str:
    """Which dialect the MCU seems to speak, from what it sent: a WHO_AM_I banner or ODOM
    frames without BATTERY frames mean seed-2025; BATTERY frames mean documented."""
    if frames.get("BATTERY", 0) > 0:
        return "documented"
    if banners or frames.get("ODOM", 0) >= 50:  # a second of odometry and no battery
        return "seed-2025"
    return "unknown"
