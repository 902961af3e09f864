"""The RPLIDAR driver against the emulated device on a real pseudo-terminal."""

import asyncio
import math

import numpy as np
import pytest

from sage_robot.core.bus import Bus
from sage_robot.core.clock import WallClock
from sage_robot.core.config import load_profile
from sage_robot.core.msgs import DiagnosticStatus, LaserScan, Level
from sage_robot.core.node import NodeContext
from sage_robot.hardware.emulators.rplidar import RplidarEmulator
from sage_robot.hardware.rplidar import protocol as p
from sage_robot.hardware.rplidar.driver import RplidarDriver, revolution_to_scan
from sage_robot.hardware.rplidar.node import LIDAR_STATUS, LidarNode


def test_sample_encoding_by_hand():
    # quality 47, start, 90.0°, 1500 mm: angle_q6 = 5760 = 0x1680, dist_q2 = 6000 = 0x1770
    raw = p.encode_sample(p.Sample(True, 47, 90.0, 1500.0))
    assert raw.hex() == "bd012d7017"  # 47<<2|S=1: bd; angle_q6 low 7 bits<<1|C: 01; high: 2d; 6000 LE: 7017
    assert p.parse_sample(raw) == p.Sample(True, 47, 90.0, 1500.0)
    with pytest.raises(p.ProtocolError):
        p.parse_sample(bytes([0b11, 1, 0, 0, 0]))  # S and !S both set


def test_descriptor_table_round_trip():
    for spec in p.RESPONSES.values():
        assert p.parse_descriptor(p.descriptor(spec)) == spec
    assert p.descriptor(p.RESPONSES[p.Command.SCAN]).hex() == "a55a0500004081"


@pytest.fixture
def emulator():
    emu = RplidarEmulator(rev_hz=20.0)
    yield emu
    emu.close()


def test_session_info_health_and_scan(emulator):
    with RplidarDriver(emulator.port_name) as lidar:
        info = lidar.info()
        assert info.model == 0x18
        assert info.firmware == (1, 29)
        assert lidar.health() == ("good", 0)
        revs = []
        for rev in lidar.revolutions():
            revs.append(rev)
            if len(revs) == 2:
                break
        lidar.stop()
    scan = revolution_to_scan(revs[1], 0.0, 0.05)
    # 3 m half-size square room: 3 m straight ahead, 3·√2 on the diagonal; CW → CCW mapping.
    front = scan.ranges[int((0.0 + math.pi) / scan.angle_increment)]
    diag = scan.ranges[int((math.pi / 4 + math.pi) / scan.angle_increment)]
    assert front == pytest.approx(3.0, abs=0.01)
    assert diag == pytest.approx(3.0 * math.sqrt(2), abs=0.05)
    assert np.isfinite(scan.ranges).sum() >= 350


def test_clockwise_device_angle_maps_to_ccw_scan():
    # Only one return, at 90° clockwise (the robot's right) → -90° in the scan.
    rev = [p.Sample(i == 0, 47, float(a), 2000.0 if a == 90 else 0.0) for i, a in enumerate(range(360))]
    scan = revolution_to_scan(rev, 0.0, 0.1)
    (idx,) = np.flatnonzero(np.isfinite(scan.ranges))
    assert scan.angles[idx] == pytest.approx(-math.pi / 2, abs=math.radians(1))


async def test_lidar_node_publishes_scans_and_survives_a_dead_port(emulator, tmp_path):
    settings = load_profile(None, {"lidar": {"port": emulator.port_name, "reconnect_s": 0.2}})
    bus = Bus(WallClock())
    node = LidarNode(NodeContext(bus, bus.clock, settings))
    sub = bus.subscribe("/scan", LaserScan)
    await node.setup()
    scan = await asyncio.wait_for(sub.get(), 5)
    assert np.isfinite(scan.ranges).sum() > 300
    assert node.stats()["connected"]
    await node.teardown()

    dead = load_profile(None, {"lidar": {"port": str(tmp_path / "ttyUSB9"), "reconnect_s": 0.2}})
    node = LidarNode(NodeContext(bus, bus.clock, dead))
    statuses = bus.subscribe(LIDAR_STATUS, DiagnosticStatus)
    await node.setup()
    for _ in range(2):  # the first attempt fails, and the node keeps retrying
        status = await asyncio.wait_for(statuses.get(), 5)
        assert status.level is Level.ERROR, status
    assert not node.stats()["connected"]
    await node.teardown()
