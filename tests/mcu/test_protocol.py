"""The protocol table, encoder and streaming decoder.

Golden vectors are written out by hand from the seed's tables (section 6): SOF 0x7E,
TYPE, LEN, then little-endian IEEE 754 float32. The float bit patterns used:
0.0 = 00000000, 0.25 = 3E800000, 0.5 = 3F000000, 1.0 = 3F800000, 3.0 = 40400000,
9.75 = 411C0000, 12.5 = 41480000; a set sign bit gives the negative (BE800000 = -0.25).
Little-endian, so 0.5 goes on the wire as 00 00 00 3F.
"""

from __future__ import annotations

import itertools
import math
import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sage_robot.hardware.mcu import protocol as proto
from sage_robot.hardware.mcu.protocol import Decoder, Frame, encode

GOLDEN = [
    (proto.CMD, (0.5, -0.25), "7e 01 08  0000003f 000080be"),
    (
        proto.ODOM,
        (1.0, -1.0, 3.0, 0.5, 0.25),
        "7e 02 14  0000803f 000080bf 00004040 0000003f 0000803e",
    ),
    (
        proto.IMU,
        (0.0, 0.0, 0.5, 1.0, -0.5, 9.75),
        "7e 03 18  00000000 00000000 0000003f 0000803f 000000bf 00001c41",
    ),
    (proto.BATTERY, (12.5,), "7e 04 04  00004841"),
]


@pytest.mark.parametrize(("kind", "values", "wire"), GOLDEN, ids=lambda x: getattr(x, "name", ""))
def test_golden_vectors_encode_and_decode(kind, values, wire):
    expected = bytes.fromhex(wire.replace(" ", ""))
    assert encode(kind, values) == expected
    frames = Decoder(accept=frozenset(proto.FRAME_TYPES)).feed(expected)
    assert frames == [Frame(kind, values)]


def test_table_matches_the_seed():
    assert proto.SOF == 0x7E
    rows = {t.code: (t.name, t.length, t.rate_hz) for t in proto.FRAME_TYPES.values()}
    assert rows == {
        0x01: ("CMD", 8, 0.0),
        0x02: ("ODOM", 20, 50.0),
        0x03: ("IMU", 24, 100.0),
        0x04: ("BATTERY", 4, 50.0),
    }
    assert proto.ODOM.field_names == ("x", "y", "theta", "v", "w")
    assert proto.IMU.field_names == ("gx", "gy", "gz", "ax", "ay", "az")
    assert proto.MAX_FRAME_LEN == 27


def test_encode_refuses_bad_values_with_a_clear_message():
    with pytest.raises(ValueError, match="CMD takes 2 values"):
        encode("CMD", (1.0,))
    with pytest.raises(ValueError, match=r"CMD\.w must be finite"):
        encode(proto.CMD, (0.0, math.nan))
    with pytest.raises(ValueError, match="unknown MCU frame type 'FOO'"):
        encode("FOO", ())
    assert proto.frame_type(0x02) is proto.ODOM
    assert proto.frame_type("imu") is proto.IMU


def test_byte_by_byte_feeding_gives_the_same_frames():
    stream = b"".join(encode(k, v) for k, v, _ in GOLDEN[1:])
    d = Decoder()
    out = [f for b in stream for f in d.feed(bytes([b]))]
    assert [f.kind.name for f in out] == ["ODOM", "IMU", "BATTERY"]
    assert d.pending == 0
    assert d.stats.bytes_dropped == 0


def test_partial_frame_waits_for_the_rest():
    frame = encode(proto.ODOM, (1.0, 2.0, 3.0, 0.1, 0.2))
    d = Decoder()
    assert d.feed(frame[:2]) == []
    assert d.pending == 2
    assert d.feed(frame[2:10]) == []
    assert d.pending == 10
    assert len(d.feed(frame[10:])) == 1
    assert d.pending == 0


def _bad(type_code: int, length: int, payload: bytes) -> bytes:
    return bytes((proto.SOF, type_code, length)) + payload


def test_every_error_kind_is_counted_and_good_frames_survive():
    good = encode(proto.BATTERY, (15.0,))
    nan_battery = _bad(0x04, 4, struct.pack("<f", math.nan))
    inf_odom = _bad(0x02, 20, struct.pack("<5f", 0.0, 0.0, 0.0, math.inf, 0.0))
    wrong_len = _bad(0x02, 16, bytes(16))  # ODOM must be 20
    unknown = _bad(0x09, 4, bytes(4))  # no such type
    implausible = _bad(0x04, 4, struct.pack("<f", 1.0e6))  # a million volts
    theta_out = _bad(0x02, 20, struct.pack("<5f", 0.0, 0.0, 7.0, 0.0, 0.0))  # > 2 pi
    garbage = b"\x01\x02\x03"
    bad = [garbage, nan_battery, inf_odom, wrong_len, unknown, implausible, theta_out]
    stream = good + b"".join(b + good for b in bad)
    d = Decoder()
    frames = d.feed(stream)
    assert frames == [Frame(proto.BATTERY, (15.0,))] * (len(bad) + 1)
    assert dict(d.stats.errors) == {
        "non_finite": 2,
        "bad_length": 1,
        "unknown_type": 1,
        "implausible": 2,
    }
    assert d.stats.bytes_dropped == sum(len(b) for b in bad)
    assert d.stats.frames["BATTERY"] == len(bad) + 1


def test_frame_hidden_after_a_rejected_sof_is_found():
    # A stray SOF right before a real frame: the candidate's TYPE is then 0x7E (unknown),
    # so it is rejected and the hunt restarts at the very next byte: the real SOF.
    good = encode(proto.ODOM, (1.0, 2.0, 3.0, 0.0, 0.0))
    d = Decoder()
    assert d.feed(b"\x7e" + good) == [Frame(proto.ODOM, (1.0, 2.0, 3.0, 0.0, 0.0))]
    assert d.stats.errors["unknown_type"] == 1
    assert d.stats.bytes_dropped == 1


def test_types_not_accepted_are_skipped_like_unknown_ones():
    d = Decoder(accept=frozenset({proto.ODOM.code}))
    out = d.feed(encode(proto.CMD, (0.1, 0.0)) + encode(proto.ODOM, (0, 0, 0, 0, 0)))
    assert [f.kind.name for f in out] == ["ODOM"]
    assert d.stats.errors["unknown_type"] == 1


def test_reset_drops_a_partial_frame():
    d = Decoder()
    d.feed(encode(proto.IMU, (0, 0, 0, 0, 0, 9.8))[:10])
    d.reset()
    assert d.pending == 0
    assert d.stats.bytes_dropped == 10


# ---------------------------------------------------------------- properties


def _f32_inside(x: float, toward: float) -> float:
    """The float32 nearest ``x`` on the ``toward`` side (bounds must be float32-exact)."""
    y = np.float32(x)
    if (toward > x and float(y) < x) or (toward < x and float(y) > x):
        y = np.nextafter(y, np.float32(toward))
    return float(y)


def _values(kind: proto.FrameType) -> st.SearchStrategy[tuple[float, ...]]:
    return st.tuples(
        *(
            st.floats(
                _f32_inside(f.low, f.high),
                _f32_inside(f.high, f.low),
                width=32,
                allow_nan=False,
                allow_infinity=False,
            )
            for f in kind.fields
        )
    )


frames_st = st.sampled_from(list(proto.FRAME_TYPES.values())).flatmap(
    lambda k: _values(k).map(lambda v: Frame(k, v))
)
garbage_no_sof = st.binary(max_size=40).map(lambda b: b.replace(b"\x7e", b""))
segment_no_sof = st.one_of(frames_st, garbage_no_sof)


def _chunked(stream: bytes, cuts: list[int]) -> list[bytes]:
    points = sorted({c % (len(stream) + 1) for c in cuts})
    edges = [0, *points, len(stream)]
    return [stream[a:b] for a, b in itertools.pairwise(edges)]


@settings(max_examples=300, deadline=None)
@given(st.lists(segment_no_sof, max_size=25), st.lists(st.integers(0, 10_000), max_size=30))
def test_frames_and_sof_free_garbage_in_any_chunking_yield_exactly_the_frames(segments, cuts):
    stream = b"".join(s.encode() if isinstance(s, Frame) else s for s in segments)
    d = Decoder()
    out = [f for chunk in _chunked(stream, cuts) for f in d.feed(chunk)]
    assert out == [s for s in segments if isinstance(s, Frame)]
    assert d.stats.bytes_dropped == sum(len(s) for s in segments if isinstance(s, bytes))
    assert not d.stats.errors


@settings(max_examples=300, deadline=None)
@given(
    st.lists(st.one_of(frames_st, st.binary(max_size=40)), max_size=25),
    st.lists(st.integers(0, 10_000), max_size=30),
)
def test_after_any_garbage_the_decoder_resynchronises(segments, cuts):
    """Garbage may contain SOF. Guarantee: a valid frame is recovered when the
    MAX_FRAME_LEN bytes before it hold no SOF, or when it directly follows a recovered
    frame. Every output frame is finite and plausible; nothing raises."""
    stream = bytearray()
    must: list[Frame] = []
    prev_recovered = True  # the stream start acts like a recovered frame
    for s in segments:
        if isinstance(s, Frame):
            window = stream[-proto.MAX_FRAME_LEN :]
            recovered = prev_recovered or (proto.SOF not in window)
            if recovered:
                must.append(s)
            prev_recovered = recovered
            stream += s.encode()
        else:
            stream += s
            prev_recovered = prev_recovered and not s
    d = Decoder()
    out = [f for chunk in _chunked(bytes(stream), cuts) for f in d.feed(chunk)]
    it = iter(out)
    assert all(any(f == g for g in it) for f in must), "a recoverable frame was lost"
    for f in out:
        assert all(math.isfinite(v) for v in f.values)
        assert all(s.low <= v <= s.high for s, v in zip(f.kind.fields, f.values, strict=True))
