"""The simulator's time on a shared page, for process groups on one machine.

The simulator's process writes, at every physics step, "simulated time ``t`` at monotonic
wall time ``wall``, paced ``speed`` times real time" into a small memory-mapped file; the
other processes of the robot read it whenever they need the time. It replaces ``/clock``
messages between processes on one machine: a message costs each follower a network wake-up
and a decode (about 0.6 ms here, five times a second, in every process), a read of the page
costs a microsecond and wakes nobody. ``/clock`` is still published for tools and for
processes on other machines (``CLOCK_MONOTONIC`` is one clock for every process of a
machine, not across machines).

The page: a 64-bit sequence number, three doubles and a CRC-32 of them, written with one
copy. A reader that catches a write half done sees a bad CRC and reads again; a page never
written (sequence 0) says "no time yet".
"""

from __future__ import annotations

import mmap
import os
import struct
import zlib
from dataclasses import dataclass
from pathlib import Path

_PAYLOAD = struct.Struct("<Qddd")  # sequence, simulated time (s), monotonic wall time (s), speed
_CRC = struct.Struct("<I")
BOARD_BYTES = _PAYLOAD.size + _CRC.size
READ_TRIES = 8  # reads of a page caught mid-write before giving up on this look


@dataclass(frozen=True)
class Reading:
    seq: int  # how many times the page was written
    t: float  # simulated time (s)
    wall: float  # time.monotonic() when the simulator was at ``t``
    speed: float  # simulated seconds per wall second (0: not paced)


def encode(seq: int, t: float, wall: float, speed: float) -> bytes:
    payload = _PAYLOAD.pack(seq, t, wall, speed)
    return payload + _CRC.pack(zlib.crc32(payload))


def decode(page: bytes) -> Reading | None:
    """The reading on ``page``, or None when it was never written or is half written."""
    payload, (crc,) = page[: _PAYLOAD.size], _CRC.unpack(page[_PAYLOAD.size : BOARD_BYTES])
    if zlib.crc32(payload) != crc:
        return None
    seq, t, wall, speed = _PAYLOAD.unpack(payload)
    return None if seq == 0 else Reading(seq, t, wall, speed)


class ClockBoard:
    """One shared page: :meth:`create` it (the supervisor), :meth:`write` it (the simulator),
    :meth:`read` it (everyone else)."""

    def __init__(self, path: Path | str) -> None:
        self.path = Path(path)
        fd = os.open(self.path, os.O_RDWR)
        try:
            self._map = mmap.mmap(fd, BOARD_BYTES)
        finally:
            os.close(fd)
        self._seq = 0
        self.torn = 0  # reads that caught a write half done (and read again)

    @classmethod
    def create(cls, path: Path | str) -> ClockBoard:
        """A new, never written page at ``path`` (replacing any old one)."""
        tmp = Path(f"{path}.new")
        tmp.write_bytes(bytes(BOARD_BYTES))
        os.replace(tmp, path)
        return cls(path)

    def write(self, t: float, wall: float, speed: float) -> None:
        if not self._seq:  # a restarted simulator goes on from the page's count
            last = self.read()
            self._seq = last.seq if last is not None else 0
        self._seq += 1
        self._map[:BOARD_BYTES] = encode(self._seq, t, wall, speed)

    def read(self) -> Reading | None:
        """The last time written, or None before the first write."""
        for _ in range(READ_TRIES):
            page = self._map[:BOARD_BYTES]
            reading = decode(page)
            if reading is not None or page == bytes(BOARD_BYTES):
                return reading
            self.torn += 1
        return None

    def close(self) -> None:
        self._map.close()
