"""DOA: the XVF3800 control map and decoding, the fallback without the device, and the
voice node's broadcast in simulation (angle toward the simulated speaker)."""

from __future__ import annotations

import asyncio
import math
import struct

import numpy as np
import pytest

from sage_robot.core.bus import Bus
from sage_robot.core.clock import SimClock
from sage_robot.core.config import Settings
from sage_robot.core.errors import DeviceNotConnectedError
from sage_robot.core.msgs.sim import SpeakerBearing
from sage_robot.core.msgs.voice import Doa
from sage_robot.core.node import NodeContext
from sage_robot.core.topics import DOA, SIM_SPEAKER
from sage_robot.hardware.doa import (
    AUTO_BEAM,
    CTRL_IN_VENDOR_DEVICE,
    PARAMETERS,
    READ_FLAG,
    STATUS_RETRY,
    DoaReadError,
    XVF3800Doa,
    azimuth_to_seed_deg,
    decode,
)
from sage_robot.voice.node import VoiceNode


def reply(status: int, *values: float) -> bytes:
    return bytes([status]) + struct.pack("<4f", *values)


def test_decode_azimuths_and_statuses():
    p = PARAMETERS["AEC_AZIMUTH_VALUES"]
    assert p.length == 17
    assert decode(p, reply(0, 0.0, 1.0, 2.0, math.pi)) == pytest.approx((0.0, 1.0, 2.0, math.pi))
    with pytest.raises(DoaReadError, match="busy"):
        decode(p, reply(STATUS_RETRY, 0, 0, 0, 0))
    with pytest.raises(DoaReadError, match="error status 3"):
        decode(p, reply(3, 0, 0, 0, 0))
    with pytest.raises(DoaReadError, match="short reply"):
        decode(p, b"\x00\x01")


def test_angle_convention():
    assert azimuth_to_seed_deg(math.pi) == pytest.approx(180.0)
    assert azimuth_to_seed_deg(-math.pi / 2) == pytest.approx(270.0)
    assert azimuth_to_seed_deg(0.0, offset_deg=90.0) == pytest.approx(90.0)


class FakeUsbDevice:
    """The XVF3800 at the USB control-transfer seam (no device here): answers reads of
    the control map like the chip, busy once, then the auto beam at 90° (left)."""

    def __init__(self) -> None:
        self.calls: list[tuple[int, int, int, int, int]] = []

    def ctrl_transfer(self, req_type, req, value, index, length, timeout):
        self.calls.append((req_type, req, value, index, length))
        if len(self.calls) == 1:
            return reply(STATUS_RETRY, 0, 0, 0, 0)
        az = [0.0, 0.0, 0.0, 0.0]
        az[AUTO_BEAM] = math.pi / 2
        return reply(0, *az)


def test_reader_speaks_the_control_protocol():
    doa = XVF3800Doa()
    dev = FakeUsbDevice()
    doa._dev = dev
    assert doa.read_deg() == 180.0  # busy: the last value (front)
    assert doa.read_deg() == pytest.approx(90.0)
    p = PARAMETERS["AEC_AZIMUTH_VALUES"]
    assert dev.calls[-1] == (CTRL_IN_VENDOR_DEVICE, 0, READ_FLAG | p.cmdid, p.resid, p.length)


def test_without_the_device_open_fails_cleanly():
    with pytest.raises(DeviceNotConnectedError, match=r"XVF3800|USB|pyusb"):
        XVF3800Doa(vid=0xFFFF, pid=0xFFFE).open()


async def run_node(settings: Settings, steps: int, publish=None) -> tuple[list[Doa], VoiceNode]:
    clock = SimClock()
    bus = Bus(clock)
    got: list[Doa] = []
    bus.subscribe(DOA, Doa, got.append, maxsize=1000)
    node = VoiceNode(NodeContext(bus, clock, settings))
    await node.setup()
    try:
        for i in range(steps):
            if publish is not None:
                publish(bus, clock, i)
            await clock.step(0.02)
    finally:
        await node._close()
        await node.teardown()
    await asyncio.sleep(0)
    return got, node


async def test_sim_doa_follows_the_simulated_speaker():
    settings = Settings.model_validate({"voice": {"enabled": False}})

    def person(bus, clock, i):
        if i == 50:  # after 1 s someone stands to the robot's right
            bus.publish(SIM_SPEAKER, SpeakerBearing(clock.now(), True, 270.0, 1.2, 4))
        if i == 100:  # and walks away
            bus.publish(SIM_SPEAKER, SpeakerBearing(clock.now(), False))

    got, _ = await run_node(settings, 150, person)
    assert len(got) == pytest.approx(150 * 0.02 * 12.5, abs=1)  # ~12.5 Hz
    assert {d.source for d in got} == {"sim"}
    angles = [d.angle_deg for d in got]
    assert angles[0] == 180.0
    assert 270.0 in angles
    assert angles[-1] == 180.0


async def test_real_mode_without_device_falls_back_to_front():
    settings = Settings.model_validate({"voice": {"enabled": False, "source": "mic"}})
    got, _ = await run_node(settings, 30)
    assert got
    assert {(d.angle_deg, d.source) for d in got} == {(180.0, "fixed")}


async def test_sim_mic_skips_only_silence_when_its_reader_falls_behind():
    from sage_robot.sim.audio import SimMicrophone

    clock = SimClock()
    mic = SimMicrophone(clock)
    first = asyncio.create_task(mic.read())
    await asyncio.sleep(0)  # the read starts: the clock is at 0
    await clock.step(0.1)
    await asyncio.wait_for(first, 5)
    await clock.step(10.0)  # the reader slept through 10 s of nothing
    await asyncio.wait_for(mic.read(), 5)
    assert mic.skipped >= 115
    assert mic.frame_time == pytest.approx(clock.now(), abs=0.2)
    mic.inject(np.full(16000, 1000, dtype=np.int16))  # a visitor speaks: nothing is skipped
    await clock.step(10.0)
    frames = [await asyncio.wait_for(mic.read(), 5) for _ in range(12)]
    assert min(int(f.mean()) for f in frames) > 900
    assert mic.skipped < 130
