"""The seed-2025 firmware model: its pure parts directly, its serial link over a real pty
(McuSimNode with ``mcu.firmware: seed-2025``; this test plays the Jetson on the slave)."""

from __future__ import annotations

import math
import os
import struct
from collections.abc import AsyncIterator

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from sage_robot.app.runtime import SIM_STEP_S
from sage_robot.core.bus import Bus
from sage_robot.core.clock import SimClock
from sage_robot.core.config import load_profile
from sage_robot.core.node import SIM_STEP_HOOKS, NodeContext
from sage_robot.hardware.mcu import protocol as proto
from sage_robot.sim.firmware import FirmwareModel, Seed2025Model, Seed2025Params, make_firmware
from sage_robot.sim.firmware.blockrx import DROPPED_BLOCK, BlockReceiver, encode_seed_command
from sage_robot.sim.firmware.encoders import EncoderOdometry, MotorEncoders
from sage_robot.sim.firmware.esc import esc_pulse
from sage_robot.sim.firmware.seed2025_params import SEED_BANNER
from sage_robot.sim.flat_floor import FlatFloor
from sage_robot.sim.mcu_pty import McuSimNode

DT = 0.01
M_PER_COUNT = math.pi * 0.101 / 250  # 100 CPR x 2 edges x 1.25 motor revs per wheel rev
TRACK = 0.483
HEADER = 0x78
ODOM_CODE, IMU_CODE = 0x02, 0x03
NO_X = st.binary(min_size=1, max_size=1).filter(lambda b: b[0] != HEADER)


class Sim:
    """The seed-2025 model on a flat floor with the firmware's own track."""

    def __init__(self, seed: int = 1) -> None:
        self.fw = Seed2025Model(Seed2025Params(), np.random.default_rng(seed))
        self.floor = FlatFloor(TRACK)
        self.k = 0
        self.out = bytearray()
        self.pwm: list[tuple[float, float]] = []
        self.u: list[tuple[float, float]] = []

    def run(self, seconds: float) -> None:
        for _ in range(round(seconds / DT)):
            self.k += 1
            t = self.k * DT
            v, w = self.floor.step(DT, self.fw.control_step(DT, t))
            self.fw.sense(DT, v, w)
            self.out += self.fw.transmit(t)
            self.pwm.append(self.fw.pwm_us)
            self.u.append(self.fw.pi_output)


def parse(stream: bytes) -> list[tuple[str, tuple[float, ...]]]:
    """The seed-2025 MCU's output, strictly: banners, ODOM and IMU frames, nothing else."""
    out: list[tuple[str, tuple[float, ...]]] = []
    i = 0
    while i < len(stream):
        if stream.startswith(SEED_BANNER, i):
            out.append(("BANNER", ()))
            i += len(SEED_BANNER)
            continue
        assert stream[i] == 0x7E, f"byte {i}: {stream[i:i + 8].hex()}"
        kind, length = stream[i + 1], stream[i + 2]
        assert (kind, length) in ((ODOM_CODE, 0x14), (IMU_CODE, 0x18)), "only ODOM and IMU frames"
        if i + 3 + length > len(stream):
            break  # the rest is still on its way
        values = struct.unpack_from(f"<{length // 4}f", stream, i + 3)
        out.append(("ODOM" if kind == ODOM_CODE else "IMU", values))
        i += 3 + length
    return out


def odom(items: list[tuple[str, tuple[float, ...]]]) -> list[tuple[float, ...]]:
    return [values for name, values in items if name == "ODOM"]


# ------------------------------------------------------------------ pure parts
def test_encoder_geometry_and_differential_drive_odometry():
    p = Seed2025Params()
    assert p.counts_per_wheel_rev == 250
    assert p.metres_per_count == pytest.approx(M_PER_COUNT)
    enc = MotorEncoders(p.metres_per_count)
    enc.roll(1.0, 1.0, 1.0)
    assert enc.counts == (math.floor(1.0 / M_PER_COUNT),) * 2 == (787, 787)
    odo = EncoderOdometry(p)
    odo.update(enc.counts, 1.0)
    assert odo.x == pytest.approx(787 * M_PER_COUNT, rel=1e-6)
    assert odo.y == 0.0
    # Spin clockwise in place: the left wheel forward, the right backward.
    enc2, odo2 = MotorEncoders(p.metres_per_count), EncoderOdometry(p)
    for _ in range(100):
        enc2.roll(DT, 0.5 * TRACK, -0.5 * TRACK)  # -1 rad/s
        odo2.update(enc2.counts, DT)
    assert odo2.theta == pytest.approx(-1.0, abs=2 * M_PER_COUNT / TRACK)
    assert math.hypot(odo2.x, odo2.y) < 1e-3


@settings(max_examples=200, deadline=None)
@given(st.lists(st.integers(-400, 400), min_size=1, max_size=60))
def test_theta_is_fmodf_and_stays_strictly_inside_two_pi(steps: list[int]):
    odo = EncoderOdometry(Seed2025Params())
    left = right = 0
    for d in steps:  # spin in place by d counts per wheel
        left, right = left - d, right + d
        odo.update((left, right), DT)
        wire = struct.unpack("<f", struct.pack("<f", odo.theta))[0]
        assert -2 * math.pi < wire < 2 * math.pi
    turned = 2 * right * M_PER_COUNT / TRACK
    assert math.remainder(odo.theta - turned, 2 * math.pi) == pytest.approx(0.0, abs=1e-3)
    if all(d <= 0 for d in steps):  # only ever clockwise: never positive
        assert odo.theta <= 0.0


def test_esc_mapping_has_only_the_linear_band_and_the_two_steps():
    assert esc_pulse(0.0) == 1500.0
    assert esc_pulse(1.0) == 1570.0
    assert esc_pulse(-1.0) == 1430.0
    assert esc_pulse(100 / 70) == 1600.0
    assert esc_pulse(-100 / 70) == 1400.0
    assert esc_pulse(1.44) == 1750.0
    assert esc_pulse(-1.44) == 1250.0
    assert esc_pulse(math.inf) == 1750.0
    assert esc_pulse(-math.inf) == 1250.0
    assert esc_pulse(math.nan) == 0.0  # NaN reaches the timer as 0: no pulse


def test_pulses_in_a_drive_are_the_band_or_the_steps_and_follow_the_pi():
    s = Sim()
    for cmd in [(0.2, 0.0), (0.5, 0.0), (0.9, 0.4), (-0.6, 0.0), (0.0, 1.2), (3.0, 0.0), (0.0, 0.0)]:
        s.fw.receive(encode_seed_command(*cmd))
        s.run(2.0)
    pulses = {x for pair in s.pwm for x in pair}
    assert pulses <= {float(p) for p in range(1400, 1601)} | {1250.0, 1750.0}
    assert {1250.0, 1750.0} <= pulses
    assert len(pulses) > 50
    for pair, u in zip(s.pwm, s.u, strict=True):
        assert pair == (esc_pulse(u[0]), esc_pulse(u[1]))


@pytest.mark.parametrize(("v", "w"), [(0.2, 0.0), (0.35, 0.0), (0.5, 0.0), (0.0, -0.8), (0.3, 0.5)])
def test_one_block_drives_the_commanded_speed_within_a_few_seconds(v: float, w: float):
    s = Sim()
    s.fw.receive(encode_seed_command(v, w))
    s.run(3.0)
    k0 = len(odom(parse(bytes(s.out))))
    s.run(2.0)
    late = np.array(odom(parse(bytes(s.out)))[k0:])
    assert late[:, 3].mean() == pytest.approx(v, abs=0.02)  # ODOM v, w: measured speeds
    assert late[:, 4].mean() == pytest.approx(w, abs=0.05)
    left, right = s.fw.wheel_speeds
    assert 0.5 * (left + right) == pytest.approx(v, abs=0.05)
    assert (right - left) / TRACK == pytest.approx(w, abs=0.15)


def test_no_watchdog_the_last_command_runs_on():
    s = Sim()
    s.fw.receive(encode_seed_command(0.3, 0.0))
    s.run(1.0)
    t_cmd = s.fw.last_command_t
    s.run(20.0)  # not a byte from the Jetson for 20 s
    assert s.fw.last_command_t == t_cmd
    assert not s.fw.watchdog_tripped
    assert s.fw.watchdog_trips == 0
    assert s.fw.wheel_speeds == pytest.approx((0.3, 0.3), abs=0.03)
    assert s.floor.pose[0] > 0.3 * 19


def test_a_block_not_starting_with_0x78_is_dropped_whole():
    rx = BlockReceiver()
    good = encode_seed_command(0.25, -0.5)
    assert rx.feed(b"\x7e" + good[1:]) == []
    assert rx.errors[DROPPED_BLOCK] == 1
    assert rx.pending == 0
    assert rx.feed(good) == [(0.25, -0.5)]
    assert rx.frames == 1
    # A documented-dialect CMD (11 bytes, 0x7E) is one dropped block and leaves 2 bytes
    # pending: the next seed command is misaligned and dropped too.
    assert rx.feed(proto.encode(proto.CMD, (0.25, -0.5))) == []
    assert rx.pending == 2
    assert rx.feed(good) == []
    assert rx.errors[DROPPED_BLOCK] == 3
    # Raw: no range check (the real firmware has none).
    assert rx.feed(good[2:] + encode_seed_command(40.0, -90.0)) == [(40.0, -90.0)]


def _no_x_payload(cmds: list[tuple[float, float]]) -> bytes:
    stream = b"".join(encode_seed_command(v, w) for v, w in cmds)
    assume(all(b != HEADER for i, b in enumerate(stream) if i % 9))
    return stream


speeds = st.tuples(st.floats(-1.0, 1.0, width=32), st.floats(-2.0, 2.0, width=32))


@settings(max_examples=300, deadline=None)
@given(
    st.integers(1, 8),
    st.lists(speeds, min_size=1, max_size=6),
    st.lists(speeds, min_size=1, max_size=4),
    st.data(),
)
def test_misaligned_by_k_bytes_nothing_applies_until_the_stream_realigns(
    k: int, before: list[tuple[float, float]], after: list[tuple[float, float]], data: st.DataObject
):
    """k extra bytes (or 9 - k lost ones): no command, never a wild one, until 9 - k
    filler bytes put a command start at a block start again; chunking does not matter."""
    extra = b"".join(data.draw(NO_X) for _ in range(k))
    filler = b"".join(data.draw(NO_X) for _ in range(9 - k))
    first, second = _no_x_payload(before), _no_x_payload(after)
    lost = data.draw(st.booleans())
    stream = (first[9 - k :] if lost else extra + first) + filler + second
    cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=6)))
    rx = BlockReceiver()
    got: list[tuple[float, float]] = []
    for a, b in zip([0, *cuts], [*cuts, len(stream)], strict=True):
        got += rx.feed(stream[a:b])
    expected = [struct.unpack("<ff", struct.pack("<ff", v, w)) for v, w in after]
    assert got == expected
    assert rx.pending == 0


def test_non_finite_commands_are_applied_raw_and_a_nan_stops_until_reboot():
    s = Sim()
    s.fw.receive(encode_seed_command(0.4, 0.0))
    s.run(3.0)
    s.fw.receive(encode_seed_command(math.nan, 0.0))
    s.run(0.05)
    assert math.isnan(s.fw.last_command[0])
    assert s.fw.non_finite_commands == 1
    assert s.fw.pwm_us == (0.0, 0.0)  # no pulse: the ESC's failsafe, the wheels coast
    s.run(3.0)
    assert s.fw.stopped
    s.fw.receive(encode_seed_command(0.3, 0.0))  # the integrator is NaN for good
    s.run(1.0)
    assert s.fw.stopped
    s.fw.reboot()
    s.fw.receive(encode_seed_command(0.3, 0.0))
    s.run(3.0)
    assert s.fw.wheel_speeds == pytest.approx((0.3, 0.3), abs=0.05)
    s.fw.receive(encode_seed_command(math.inf, 0.0))  # saturates at the step
    s.run(0.05)
    assert s.fw.pwm_us == (1750.0, 1750.0)


# ------------------------------------------------------------------ over a real pty
class Jetson:
    """McuSimNode (seed-2025) behind its pty; the test holds the slave side."""

    def __init__(self, sim: McuSimNode, clock: SimClock, fd: int) -> None:
        self.sim, self.clock, self.fd = sim, clock, fd
        self.received = bytearray()

    @property
    def fw(self) -> Seed2025Model:
        assert isinstance(self.sim.firmware, Seed2025Model)
        return self.sim.firmware

    def send(self, data: bytes) -> None:
        os.write(self.fd, data)

    async def run(self, seconds: float) -> None:
        for _ in range(round(seconds / SIM_STEP_S)):
            hooks = self.sim.ctx.resources[SIM_STEP_HOOKS]
            for hook in list(hooks):
                hook(SIM_STEP_S)
            await self.clock.step(SIM_STEP_S)
            self._read()

    def _read(self) -> None:
        while True:
            try:
                chunk = os.read(self.fd, 4096)
            except BlockingIOError:
                return
            if not chunk:
                return
            self.received += chunk

    def items(self) -> list[tuple[str, tuple[float, ...]]]:
        return parse(bytes(self.received))


async def _node(dialect: str) -> tuple[McuSimNode, SimClock]:
    clock = SimClock()
    ctx = NodeContext(Bus(clock), clock, load_profile(None, {"mcu": {"firmware": dialect}}))
    ctx.resources[SIM_STEP_HOOKS] = []
    sim = McuSimNode(ctx)
    await sim.setup()
    return sim, clock


@pytest.fixture
async def jetson() -> AsyncIterator[Jetson]:
    sim, clock = await _node("seed-2025")
    fd = os.open(sim.pty.port_name, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    try:
        yield Jetson(sim, clock, fd)
    finally:
        os.close(fd)
        await sim._close()
        await sim.teardown()


@pytest.mark.parametrize(("dialect", "model"), [("seed-2025", Seed2025Model), ("documented", FirmwareModel)])
async def test_mcu_sim_node_builds_the_dialect_the_settings_name(dialect: str, model: type):
    sim, _ = await _node(dialect)
    try:
        assert type(sim.firmware) is model
        assert sim.stats()["watchdog_trips"] == 0
    finally:
        await sim.teardown()
    with pytest.raises(ValueError, match="known: documented, seed-2025"):
        make_firmware("seed-2024", 0.381, np.random.default_rng(0))


async def test_over_the_pty_a_block_drives_and_odom_reports_it_with_no_battery(jetson: Jetson):
    await jetson.run(1.0)
    jetson.send(encode_seed_command(0.3, 0.0))  # once: no watchdog to feed
    await jetson.run(5.0)
    items = jetson.items()
    assert items[0] == ("BANNER", ())  # before the first frame
    names = [name for name, _ in items]
    assert names.count("BANNER") == 1
    assert "BATTERY" not in names
    assert names.count("ODOM") in (299, 300)
    assert names.count("IMU") in (599, 600)  # 50 / 100 Hz
    assert jetson.fw.frames_sent["BATTERY"] == 0
    assert jetson.fw.rx.frames == 1
    late = np.array(odom(items)[-50:])
    assert late[:, 3].mean() == pytest.approx(0.3, abs=0.02)
    assert abs(late[:, 4].mean()) < 0.02
    assert late[-1][0] == pytest.approx(jetson.sim.floor.pose[0], abs=0.02)


async def test_over_the_pty_theta_goes_negative_after_a_clockwise_turn(jetson: Jetson):
    jetson.send(encode_seed_command(0.0, -1.5))
    await jetson.run(6.0)  # about -8.5 rad: past one full clockwise turn
    thetas = [values[2] for values in odom(jetson.items())]
    assert all(-2 * math.pi < t <= 0.0 for t in thetas)
    assert min(thetas) < -5.5
    assert thetas[-1] > -4.0  # wrapped by fmodf toward zero


async def test_reboot_sends_the_banner_again_zeroes_odometry_and_stops(jetson: Jetson):
    jetson.send(encode_seed_command(0.3, 0.0))
    await jetson.run(3.0)
    jetson.fw.reboot()
    await jetson.run(3.0)
    items = jetson.items()
    banners = [i for i, (name, _) in enumerate(items) if name == "BANNER"]
    assert len(banners) == 2
    assert banners[0] == 0
    second = banners[1]
    after = [values for name, values in items[second:] if name == "ODOM"]
    assert abs(after[0][0]) < 0.01  # odometry restarted at zero
    assert jetson.fw.last_command == (0.0, 0.0)
    assert jetson.fw.last_command_t is None
    assert jetson.fw.stopped
    assert after[-1][3] == 0.0


async def test_reboot_with_a_partial_block_pending_misaligns_the_stream(jetson: Jetson):
    cmds = [encode_seed_command(0.2 + 0.01 * i, 0.1) for i in range(5)]
    assert all(HEADER not in c[1:] for c in cmds)
    jetson.send(cmds[0][:4])
    await jetson.run(0.05)
    assert jetson.fw.rx.pending == 4
    jetson.fw.reboot()
    jetson.send(cmds[0][4:] + cmds[1] + cmds[2] + cmds[3])  # the rest, then three whole ones
    await jetson.run(0.5)
    assert jetson.fw.rx.frames == 0
    assert jetson.fw.rx.errors[DROPPED_BLOCK] == 3
    assert jetson.fw.last_command == (0.0, 0.0)
    assert jetson.fw.rx.pending == 5
    jetson.send(bytes(4) + cmds[4])  # 4 filler bytes complete the stray block: aligned
    await jetson.run(0.05)
    assert jetson.fw.rx.frames == 1
    assert jetson.fw.last_command == struct.unpack("<ff", cmds[4][1:])
