"""The firmware's command RX state machine (seed section 6, "STM32 RX State Machine").

1. hunt byte by byte for SOF (0x7E: the seed's text says 0x78, the robot's firmware and
   every frame it sends use 0x7E); 2. read TYPE and LEN, which must be CMD and 8;
3. collect the payload within RX_TIMEOUT_S of the SOF; 4. parse the two floats
(finite ones only) and return to hunting. Any error returns to hunting (counted).
"""

from __future__ import annotations

import math
import struct
from collections import Counter
from enum import Enum

from sage_robot.hardware.mcu.protocol import CMD, SOF
from sage_robot.sim.firmware.params import RX_TIMEOUT_S


class RxState(Enum):
    HUNT = 0
    TYPE = 1
    LEN = 2
    PAYLOAD = 3


class CommandReceiver:
    """Feed bytes (with the firmware's time); completed commands come back as (v, w)."""

    def __init__(self, timeout_s: float = RX_TIMEOUT_S) -> None:
        self.timeout_s = timeout_s
        self.state = RxState.HUNT
        self._payload = bytearray()
        self._started = 0.0
        self.errors: Counter[str] = Counter()
        self.frames = 0

    def feed(self, data: bytes, now: float) -> list[tuple[float, float]]:
        out: list[tuple[float, float]] = []
        for byte in data:
            if self.state is not RxState.HUNT and now - self._started > self.timeout_s:
                self.errors["timeout"] += 1
                self.state = RxState.HUNT
            if self.state is RxState.HUNT:
                if byte == SOF:
                    self.state, self._started = RxState.TYPE, now
                else:
                    self.errors["garbage_bytes"] += 1
            elif self.state is RxState.TYPE:
                self._expect(byte == CMD.code, RxState.LEN, "bad_type")
            elif self.state is RxState.LEN:
                self._expect(byte == CMD.length, RxState.PAYLOAD, "bad_length")
                self._payload.clear()
            else:
                self._payload.append(byte)
                if len(self._payload) == CMD.length:
                    self.state = RxState.HUNT
                    v, w = struct.unpack("<ff", self._payload)
                    if math.isfinite(v) and math.isfinite(w):
                        self.frames += 1
                        out.append((v, w))
                    else:
                        self.errors["non_finite"] += 1
        return out

    def _expect(self, ok: bool, next_state: RxState, error: str) -> None:
        if ok:
            self.state = next_state
        else:
            self.errors[error] += 1
            self.state = RxState.HUNT
