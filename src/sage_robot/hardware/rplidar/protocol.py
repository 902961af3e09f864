"""The RPLIDAR A1/A2 serial protocol (Slamtec "RPLIDAR Interface Protocol"), as data.

Requests: ``0xA5 CMD`` (plus ``SIZE PAYLOAD CHECKSUM`` for commands with a payload).
Responses start with a 7-byte descriptor ``0xA5 0x5A LEN(30 bits)|MODE(2 bits) TYPE``.
A legacy scan streams 5-byte samples:

    byte 0: quality(6) << 2 | !S << 1 | S        S = first sample of a new revolution
    byte 1: angle_q6[6:0] << 1 | C               C = check bit, always 1
    byte 2: angle_q6[14:7]                       angle = angle_q6 / 64 degrees, clockwise
    byte 3-4: distance_q2 (uint16 LE)            distance = distance_q2 / 4 mm (0 = no return)
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from enum import IntEnum

SYNC_REQUEST = 0xA5
SYNC_RESPONSE = 0x5A
DESCRIPTOR_LEN = 7
SAMPLE_LEN = 5
BAUD = 115200


class Command(IntEnum):
    STOP = 0x25
    RESET = 0x40
    SCAN = 0x20
    FORCE_SCAN = 0x21
    GET_INFO = 0x50
    GET_HEALTH = 0x52


class SendMode(IntEnum):
    SINGLE = 0x0
    MULTIPLE = 0x1


@dataclass(frozen=True)
class ResponseSpec:
    length: int
    mode: SendMode
    data_type: int


# What each request answers: one table for the driver and the emulator.
RESPONSES: dict[Command, ResponseSpec] = {
    Command.GET_INFO: ResponseSpec(20, SendMode.SINGLE, 0x04),
    Command.GET_HEALTH: ResponseSpec(3, SendMode.SINGLE, 0x06),
    Command.SCAN: ResponseSpec(SAMPLE_LEN, SendMode.MULTIPLE, 0x81),
    Command.FORCE_SCAN: ResponseSpec(SAMPLE_LEN, SendMode.MULTIPLE, 0x81),
}

HEALTH_STATUS = {0: "good", 1: "warning", 2: "error"}


class ProtocolError(ValueError):
    """Bytes that do not follow the protocol."""


def request(cmd: Command) -> bytes:
    return bytes((SYNC_REQUEST, cmd))


def descriptor(spec: ResponseSpec) -> bytes:
    word = (spec.length & 0x3FFFFFFF) | (int(spec.mode) << 30)
    return bytes((SYNC_REQUEST, SYNC_RESPONSE)) + struct.pack("<I", word) + bytes((spec.data_type,))


def parse_descriptor(raw: bytes) -> ResponseSpec:
    if len(raw) != DESCRIPTOR_LEN or raw[0] != SYNC_REQUEST or raw[1] != SYNC_RESPONSE:
        raise ProtocolError(f"bad response descriptor {raw.hex()}")
    (word,) = struct.unpack("<I", raw[2:6])
    return ResponseSpec(word & 0x3FFFFFFF, SendMode(word >> 30), raw[6])


@dataclass(frozen=True)
class DeviceInfo:
    model: int
    firmware: tuple[int, int]
    hardware: int
    serial: str


def encode_info(info: DeviceInfo) -> bytes:
    return bytes((info.model, info.firmware[1], info.firmware[0], info.hardware)) + bytes.fromhex(info.serial)


def parse_info(raw: bytes) -> DeviceInfo:
    if len(raw) != 20:
        raise ProtocolError(f"device info must be 20 bytes, got {len(raw)}")
    return DeviceInfo(raw[0], (raw[2], raw[1]), raw[3], raw[4:20].hex().upper())


def encode_health(status: int, error_code: int = 0) -> bytes:
    return struct.pack("<BH", status, error_code)


def parse_health(raw: bytes) -> tuple[str, int]:
    if len(raw) != 3:
        raise ProtocolError(f"health must be 3 bytes, got {len(raw)}")
    status, code = struct.unpack("<BH", raw)
    return HEALTH_STATUS.get(status, f"unknown({status})"), code


@dataclass(frozen=True)
class Sample:
    start: bool  # first sample of a revolution
    quality: int  # 0..63
    angle_deg: float  # clockwise, 0..360
    distance_mm: float  # 0 = no return


def encode_sample(s: Sample) -> bytes:
    angle_q6 = round(s.angle_deg * 64.0) & 0x7FFF
    dist_q2 = min(round(s.distance_mm * 4.0), 0xFFFF)
    b0 = ((s.quality & 0x3F) << 2) | ((0 if s.start else 1) << 1) | (1 if s.start else 0)
    return bytes((b0, ((angle_q6 & 0x7F) << 1) | 1, angle_q6 >> 7)) + struct.pack("<H", dist_q2)


def parse_sample(raw: bytes) -> Sample:
    """One 5-byte sample; raises ProtocolError when its check bits are wrong (lost sync)."""
    b0, b1, b2, d = raw[0], raw[1], raw[2], struct.unpack("<H", raw[3:5])[0]
    s, not_s = b0 & 1, (b0 >> 1) & 1
    if s == not_s or not (b1 & 1):
        raise ProtocolError(f"sample check bits wrong: {raw.hex()}")
    angle_q6 = (b1 >> 1) | (b2 << 7)
    return Sample(bool(s), b0 >> 2, angle_q6 / 64.0, d / 4.0)
