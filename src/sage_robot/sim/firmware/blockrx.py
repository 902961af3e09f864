"""The seed-2025 firmware's command reception: fixed 9-byte blocks, no hunting.

The real firmware arms ``HAL_UART_Receive_IT(&huart, buf, 9)`` and re-arms it in the
RX-complete callback. So the byte stream is cut into 9-byte blocks counted from the last
(re)arm, whatever the bytes are: a block whose first byte is 0x78 ('x') is a command,
``0x78 + float32 v (m/s) + float32 w (rad/s)``, little-endian, no length, no checksum,
applied at once with no range check; any other block is dropped whole. A partial block
waits (no timeout) for its remaining bytes. A byte lost or added on the line therefore
shifts every later block until the stream happens to put 0x78 at a block start again.
"""

from __future__ import annotations

import struct
from collections import Counter

SEED_CMD_HEADER = 0x78  # 'x': first byte of a seed-2025 command block
CMD_BLOCK_BYTES = 9  # the UART's fixed reception size: header + 2 x float32
CMD_PAYLOAD = struct.Struct("<ff")  # v (m/s), w (rad/s)
DROPPED_BLOCK = "dropped_blocks"  # errors key: a block not starting with 0x78


def encode_seed_command(v: float, w: float) -> bytes:
    """The Jetson's 9-byte command block for (v m/s, w rad/s)."""
    return bytes((SEED_CMD_HEADER,)) + CMD_PAYLOAD.pack(v, w)


class BlockReceiver:
    """Feed bytes; whole blocks starting with 0x78 come back as raw (v, w) floats.

    ``frames``: blocks applied; ``errors[DROPPED_BLOCK]``: blocks dropped whole;
    ``pending``: bytes of the block being received.
    """

    def __init__(self) -> None:
        self._block = bytearray()
        self.frames = 0
        self.errors: Counter[str] = Counter()
        self.bytes_in = 0

    @property
    def pending(self) -> int:
        return len(self._block)

    def feed(self, data: bytes) -> list[tuple[float, float]]:
        self.bytes_in += len(data)
        buf = bytes(self._block) + bytes(data)
        whole = len(buf) - len(buf) % CMD_BLOCK_BYTES
        out: list[tuple[float, float]] = []
        for start in range(0, whole, CMD_BLOCK_BYTES):
            if buf[start] == SEED_CMD_HEADER:
                self.frames += 1
                v, w = CMD_PAYLOAD.unpack_from(buf, start + 1)
                out.append((v, w))
            else:
                self.errors[DROPPED_BLOCK] += 1
        self._block = bytearray(buf[whole:])
        return out

    def rearm(self) -> None:
        """Reception armed afresh (after a reboot): the next byte starts a new block."""
        self._block.clear()
