"""The firmware dialects' command writers, the stop burst, the boot banner and the
alignment watch (pure parts; the pty tests are in test_seed2025_link.py)."""

from __future__ import annotations

import struct

import pytest
from hypothesis import given
from hypothesis import strategies as st

from sage_robot.core.errors import ConfigError
from sage_robot.hardware.mcu import protocol as proto
from sage_robot.hardware.mcu.alignment import AlignmentWatch
from sage_robot.hardware.mcu.dialects import DOCUMENTED, SEED_2025, BannerWatch, dialect, guess

speeds = st.floats(-5.0, 5.0, allow_nan=False, width=32)


def firmware_blocks(stream: bytes, offset: int) -> list[tuple[float, float]]:
    """What the seed-2025 firmware applies from ``stream`` when its 9-byte blocks start
    ``offset`` bytes in: every block whose first byte is 0x78 (the facts of the issue)."""
    out = []
    for i in range(offset, len(stream) - 8, 9):
        block = stream[i:i + 9]
        if block[0] == 0x78:
            out.append(struct.unpack("<ff", block[1:]))
    return out


@given(v=speeds, w=speeds)
def test_a_seed_2025_payload_never_holds_the_header_byte(v: float, w: float) -> None:
    data = SEED_2025.command(v, w)
    assert len(data) == 9
    assert data[0] == 0x78
    assert 0x78 not in data[1:]
    got_v, got_w = SEED_2025.command_values(data)
    for sent, got in ((v, got_v), (w, got_w)):
        assert abs(got) <= abs(struct.unpack("<f", struct.pack("<f", sent))[0])  # toward zero, never faster
        assert got == pytest.approx(sent, rel=0.008, abs=1e-30)


def test_a_float_with_the_header_byte_moves_to_the_nearest_one_without_it() -> None:
    value = struct.unpack("<f", bytes((0x78, 0x56, 0x34, 0x3E)))[0]  # 0x78 in its low byte
    data = SEED_2025.command(value, 0.0)
    assert 0x78 not in data[1:]
    assert data[1:5] == bytes((0x77, 0x56, 0x34, 0x3E))  # one last-bit step toward zero
    high = struct.unpack("<f", bytes((0x12, 0x34, 0x78, 0xBF)))[0]  # 0x78 in the mantissa's top byte
    got = SEED_2025.command_values(SEED_2025.command(high, 0.0))[0]
    assert struct.pack("<f", got) == bytes((0xFF, 0xFF, 0x77, 0xBF))
    assert -0.97 < high < got < 0


@given(v=speeds, w=speeds, offset=st.integers(0, 8), extra=st.integers(0, 8))
def test_misaligned_seed_firmware_never_reads_a_wild_command(
    v: float, w: float, offset: int, extra: int
) -> None:
    """Whatever the alignment, a block that starts with the header is one of SAGE's own
    commands: a misaligned firmware drops blocks, it never applies garbage."""
    stream = b"\x00" * extra + b"".join(SEED_2025.command(v, w) for _ in range(5))
    sent = SEED_2025.command_values(SEED_2025.command(v, w))
    for applied in firmware_blocks(stream, offset):
        assert applied == pytest.approx(sent)


@pytest.mark.parametrize("offset", range(9))
def test_the_stop_burst_is_applied_at_every_alignment_and_keeps_it(offset: int) -> None:
    moving = SEED_2025.command(0.4, 0.0)
    stream = moving * 3 + SEED_2025.stop() + moving
    applied = firmware_blocks(stream, offset)
    assert applied.count((0.0, 0.0)) == 1  # exactly one copy lands on a block start
    aligned_before = offset % 9 == 0
    # The burst is ten blocks: the moving command after it is read exactly when it was before.
    assert (applied[-1] != (0.0, 0.0)) == aligned_before
    assert len(SEED_2025.stop()) % 9 == 0


def test_one_filler_byte_shifts_the_alignment_by_one() -> None:
    cmd = SEED_2025.command(0.3, 0.0)
    for offset in range(1, 9):  # blocks start `offset` bytes into each frame: `offset` fillers realign
        stream = cmd * 2 + SEED_2025.realign_step() * offset + cmd * 2
        assert firmware_blocks(stream[: 18], offset) == []
        assert firmware_blocks(stream, offset)[-1] == pytest.approx((0.3, 0.0))


def test_the_documented_dialect_writes_framed_commands() -> None:
    assert DOCUMENTED.command(0.2, -0.1) == proto.encode(proto.CMD, (0.2, -0.1))
    assert DOCUMENTED.stop() == proto.encode(proto.CMD, (0.0, 0.0))
    assert DOCUMENTED.realign_step() == b""
    frames = proto.Decoder().feed(DOCUMENTED.command(0.2, -0.1))
    assert frames[0].values == pytest.approx((0.2, -0.1))


def test_unknown_dialect_is_a_clear_error() -> None:
    with pytest.raises(ConfigError, match=r"unknown dialect 'stm32-v9'.*seed-2025"):
        dialect("stm32-v9")


def test_negative_theta_from_seed_2025_is_accepted_and_wrapped() -> None:
    from sage_robot.hardware.mcu.convert import odometry_from

    frame = proto.encode(proto.ODOM, (1.0, -0.5, -5.0, 0.2, -0.3))
    (decoded,) = proto.Decoder().feed(frame)
    odom = odometry_from(decoded.values, 0.0)
    assert odom.pose.theta == pytest.approx(-5.0 + 2 * 3.141592653589793, abs=1e-6)
    implausible = proto.encode(proto.ODOM, (1.0, -0.5, -7.0, 0.2, -0.3))
    assert proto.Decoder().feed(implausible) == []  # beyond what any firmware sends


@given(cut=st.integers(1, 20))
def test_the_banner_is_found_in_any_chunking(cut: int) -> None:
    stream = b"\x7e\x02garbage" + b"WHO_AM_I=0x71\r\n" + proto.encode(proto.ODOM, (0, 0, 0, 0, 0))
    watch = BannerWatch()
    hits = [watch.feed(stream[i:i + cut]) for i in range(0, len(stream), cut)]
    assert sum(hits) == 1
    assert watch.last == "WHO_AM_I=0x71"
    assert watch.banners == 1


def test_the_dialect_is_guessed_from_what_the_mcu_sends() -> None:
    assert guess({"ODOM": 500, "BATTERY": 500}, 0) == "documented"
    assert guess({"ODOM": 500}, 0) == "seed-2025"
    assert guess({}, 1) == "seed-2025"
    assert guess({"ODOM": 3}, 0) == "unknown"


def test_alignment_watch_steps_when_commands_stop_taking_effect() -> None:
    watch = AlignmentWatch(settle_s=0.5, stop_settle_s=0.8, step_every_s=0.3)
    moving, still = (0.3, 0.0), (0.0, 0.0)
    assert watch.update(moving, still, 0.0) == ""
    assert watch.update(moving, still, 0.4) == ""  # still settling
    assert watch.update(moving, still, 0.5) == "step"
    assert watch.update(moving, still, 0.6) == ""  # one step per 0.3 s
    assert watch.update(moving, still, 0.8) == "step"
    assert watch.update(moving, (0.29, 0.0), 0.9) == ""  # it moves now: realigned
    assert watch.update(moving, (0.29, 0.0), 5.0) == ""
    assert watch.update((0.0, 0.0), (0.29, 0.0), 5.1) == ""  # braking is not a mismatch yet
    assert watch.update((0.0, 0.0), (0.2, 0.0), 5.9) == "stop"  # still moving 0.8 s after the stop
    assert (watch.steps, watch.stops) == (2, 1)
