"""The STM32 serial protocol as data: one table of frame types read by the encoder and
the decoder (seed section 6).

Wire format of every frame::

    byte 0   SOF  = 0x7E
    byte 1   TYPE (FRAME_TYPES key)
    byte 2   LEN  (payload bytes = 4 x number of fields)
    byte 3+  payload: little-endian IEEE 754 float32, in the table's field order

There is no checksum. The decoder limits the damage of corrupted bytes by checking
that TYPE is known, that LEN matches the type exactly, that every value is finite and
that every value lies in the field's plausible range; a rejected candidate frame costs
only its SOF byte, and the hunt for the next SOF starts at the byte after it, so a
real frame hidden inside a rejected one is still found. See docs/mcu.md.
"""

from __future__ import annotations

import math
import struct
from collections import Counter
from dataclasses import dataclass, field
from enum import Enum

SOF = 0x7E  # start of frame (the seed's RX text says 0x78: the firmware sends 0x7E)
HEADER_LEN = 3  # SOF, TYPE, LEN
FLOAT_BYTES = 4
TWO_PI = 2.0 * math.pi


class Direction(str, Enum):
    TO_MCU = "jetson->mcu"
    FROM_MCU = "mcu->jetson"


@dataclass(frozen=True)
class FieldSpec:
    """One float32 field of a payload: name, unit and the plausible range [low, high]."""

    name: str
    unit: str
    low: float
    high: float


@dataclass(frozen=True)
class FrameType:
    """One row of the protocol table."""

    code: int
    name: str
    direction: Direction
    rate_hz: float  # nominal send rate; 0 = on demand
    fields: tuple[FieldSpec, ...]

    @property
    def length(self) -> int:
        """Payload length in bytes (the LEN byte)."""
        return FLOAT_BYTES * len(self.fields)

    @property
    def frame_length(self) -> int:
        return HEADER_LEN + self.length

    @property
    def codec(self) -> struct.Struct:
        return _CODECS[self.code]

    @property
    def field_names(self) -> tuple[str, ...]:
        return tuple(f.name for f in self.fields)


# Plausibility limits: far outside anything the seed's robot can do, well inside what a
# flipped bit in an exponent produces.
MAX_SPEED_MPS = 5.0
MAX_TURN_RADPS = 20.0
MAX_POSITION_M = 1.0e5  # 100 km of dead reckoning
THETA_SLACK_RAD = 1e-3  # float32 rounding at the ends of (-2 pi, 2 pi)
MAX_GYRO_RADPS = 35.0  # BNO08x full scale is 2000 deg/s ~ 34.9 rad/s
MAX_ACCEL_MPS2 = 160.0  # 16 g
MAX_BATTERY_V = 60.0

CMD = FrameType(
    0x01,
    "CMD",
    Direction.TO_MCU,
    0.0,
    (
        FieldSpec("v", "m/s", -MAX_SPEED_MPS, MAX_SPEED_MPS),
        FieldSpec("w", "rad/s", -MAX_TURN_RADPS, MAX_TURN_RADPS),
    ),
)
ODOM = FrameType(
    0x02,
    "ODOM",
    Direction.FROM_MCU,
    50.0,
    (
        FieldSpec("x", "m", -MAX_POSITION_M, MAX_POSITION_M),
        FieldSpec("y", "m", -MAX_POSITION_M, MAX_POSITION_M),
        # The documented firmware wraps theta to [0, 2 pi); the seed-2025 firmware sends
        # fmodf(theta, 2 pi), negative after a net clockwise turn: both are accepted.
        FieldSpec("theta", "rad", -TWO_PI - THETA_SLACK_RAD, TWO_PI + THETA_SLACK_RAD),
        FieldSpec("v", "m/s", -MAX_SPEED_MPS, MAX_SPEED_MPS),
        FieldSpec("w", "rad/s", -MAX_TURN_RADPS, MAX_TURN_RADPS),
    ),
)
IMU = FrameType(
    0x03,
    "IMU",
    Direction.FROM_MCU,
    100.0,
    tuple(FieldSpec(n, "rad/s", -MAX_GYRO_RADPS, MAX_GYRO_RADPS) for n in ("gx", "gy", "gz"))
    + tuple(FieldSpec(n, "m/s^2", -MAX_ACCEL_MPS2, MAX_ACCEL_MPS2) for n in ("ax", "ay", "az")),
)
BATTERY = FrameType(
    0x04,
    "BATTERY",
    Direction.FROM_MCU,
    50.0,
    (FieldSpec("voltage", "V", 0.0, MAX_BATTERY_V),),
)

FRAME_TYPES: dict[int, FrameType] = {t.code: t for t in (CMD, ODOM, IMU, BATTERY)}
BY_NAME: dict[str, FrameType] = {t.name: t for t in FRAME_TYPES.values()}
_CODECS: dict[int, struct.Struct] = {
    t.code: struct.Struct("<" + "f" * len(t.fields)) for t in FRAME_TYPES.values()
}
MAX_FRAME_LEN = max(t.frame_length for t in FRAME_TYPES.values())  # 27 bytes (IMU)


class ErrorKind(str, Enum):
    """Every way bytes can fail to become a frame (each is counted)."""

    UNKNOWN_TYPE = "unknown_type"  # SOF followed by a TYPE not in the table
    BAD_LENGTH = "bad_length"  # known TYPE with the wrong LEN
    NON_FINITE = "non_finite"  # NaN or inf in the payload
    IMPLAUSIBLE = "implausible"  # a value outside its field's range


@dataclass(frozen=True)
class Frame:
    """A decoded frame: its table row and the values in field order."""

    kind: FrameType
    values: tuple[float, ...]

    def as_dict(self) -> dict[str, float]:
        return dict(zip(self.kind.field_names, self.values, strict=True))

    def encode(self) -> bytes:
        return encode(self.kind, self.values)


def frame_type(kind: FrameType | str | int) -> FrameType:
    """Look a type up by row, name ('ODOM') or code (0x02)."""
    if isinstance(kind, FrameType):
        return kind
    found = BY_NAME.get(kind.upper()) if isinstance(kind, str) else FRAME_TYPES.get(kind)
    if found is None:
        raise ValueError(f"unknown MCU frame type {kind!r}; known: {', '.join(BY_NAME)}")
    return found


def encode(kind: FrameType | str | int, values: tuple[float, ...] | list[float]) -> bytes:
    """Encode one frame. Raises ValueError for a wrong value count or a non-finite value."""
    row = frame_type(kind)
    if len(values) != len(row.fields):
        raise ValueError(
            f"{row.name} takes {len(row.fields)} values ({', '.join(row.field_names)}), got {len(values)}"
        )
    for spec, value in zip(row.fields, values, strict=True):
        if not math.isfinite(value):
            raise ValueError(f"{row.name}.{spec.name} must be finite, got {value}")
    return bytes((SOF, row.code, row.length)) + row.codec.pack(*values)


@dataclass
class DecoderStats:
    """Counters of a :class:`Decoder` (all monotonic)."""

    bytes_in: int = 0
    bytes_dropped: int = 0  # bytes that did not end up in a valid frame
    frames: Counter[str] = field(default_factory=Counter)  # by type name
    errors: Counter[str] = field(default_factory=Counter)  # by ErrorKind value

    def as_dict(self) -> dict[str, object]:
        return {
            "bytes_in": self.bytes_in,
            "bytes_dropped": self.bytes_dropped,
            "frames": dict(self.frames),
            "errors": dict(self.errors),
        }


class Decoder:
    """Streaming decoder: feed bytes in any chunking, get whole valid frames back.

    Guarantee (tested): for any interleaving of valid frames and garbage that contains no
    SOF byte (0x7E), in any chunking, the output is exactly the valid frames in order.
    Garbage that does contain 0x7E may produce a bogus frame whose values pass every
    check (there is no checksum), but the decoder resynchronises: every valid frame that
    starts at least MAX_FRAME_LEN bytes after the last 0x7E of the garbage is recovered.
    """

    def __init__(self, accept: frozenset[int] | None = None) -> None:
        """``accept``: type codes to yield (default: every known type)."""
        self._buf = bytearray()
        self._accept = accept if accept is not None else frozenset(FRAME_TYPES)
        self.stats = DecoderStats()

    def feed(self, data: bytes) -> list[Frame]:
        """Add bytes; return every frame completed by them."""
        self.stats.bytes_in += len(data)
        buf = self._buf
        buf.extend(data)
        out: list[Frame] = []
        i, n = 0, len(buf)
        while i < n:
            j = buf.find(SOF, i)
            if j < 0:
                self.stats.bytes_dropped += n - i
                i = n
                break
            self.stats.bytes_dropped += j - i
            i = j
            if n - i < HEADER_LEN:
                break  # wait for the header
            row = FRAME_TYPES.get(buf[i + 1])
            if row is None or row.code not in self._accept:
                i = self._reject(i, ErrorKind.UNKNOWN_TYPE)
                continue
            if buf[i + 2] != row.length:
                i = self._reject(i, ErrorKind.BAD_LENGTH)
                continue
            end = i + row.frame_length
            if end > n:
                break  # wait for the payload
            values = row.codec.unpack_from(buf, i + HEADER_LEN)
            problem = _check(row, values)
            if problem is not None:
                i = self._reject(i, problem)
                continue
            out.append(Frame(row, values))
            self.stats.frames[row.name] += 1
            i = end
        del buf[:i]
        return out

    def _reject(self, i: int, kind: ErrorKind) -> int:
        """Count the error and drop the SOF byte only: the hunt restarts at i + 1."""
        self.stats.errors[kind.value] += 1
        self.stats.bytes_dropped += 1
        return i + 1

    def reset(self) -> None:
        """Forget a partial frame (the port was reopened); its bytes count as dropped."""
        self.stats.bytes_dropped += len(self._buf)
        self._buf.clear()

    @property
    def pending(self) -> int:
        """Bytes held back waiting for the rest of a frame."""
        return len(self._buf)


def _check(row: FrameType, values: tuple[float, ...]) -> ErrorKind | None:
    for spec, value in zip(row.fields, values, strict=True):
        if not math.isfinite(value):
            return ErrorKind.NON_FINITE
        if not spec.low <= value <= spec.high:
            return ErrorKind.IMPLAUSIBLE
    return None
