"""The real serial bridge against the seed-2025 firmware model over a real pty, on the
simulated clock: drive, stop, misalignment by 1..8 bytes and its repair, a stop while
misaligned, a reboot mid-stream, negative theta through to /odom, no battery → unknown.
(The same bridge against the documented model: test_bridge.py; the pure parts:
test_dialects.py; kill -9 under the supervisor for both dialects: test_supervisor.py.)"""

from __future__ import annotations

import math
from collections.abc import AsyncIterator

import pytest

from sage_robot.core import topics
from sage_robot.core.msgs import Event

from .rig import Rig, close_rig, make_rig

REALIGN_BOUND_S = 0.5 + 9 * 0.3 + 1.0  # settle, up to 8 filler steps, the motors' answer


@pytest.fixture
async def seed() -> AsyncIterator[Rig]:
    rig = await make_rig({"mcu": {"firmware": "seed-2025"}})
    try:
        yield rig
    finally:
        await close_rig(rig)


def _record_applied(rig: Rig) -> list[tuple[float, float]]:
    """Every command the firmware model's block receiver hands to the motors."""
    applied: list[tuple[float, float]] = []
    feed = rig.firmware.rx.feed

    def spy(data: bytes) -> list[tuple[float, float]]:
        out = feed(data)
        applied.extend(out)
        return out

    rig.firmware.rx.feed = spy
    return applied


STILL_MPS = 0.02  # the seed-2025 PI has no stop path: its integrator decays over ~3 s
STOP_BOUND_S = 6.0


def _still(rig: Rig) -> bool:
    return all(abs(s) < STILL_MPS for s in rig.firmware.wheel_speeds)


def _moving(rig: Rig, v: float, tol: float = 0.08) -> bool:
    return bool(rig.odom) and abs(rig.odom[-1].twist.linear_x - v) < tol


async def test_drive_and_stop(seed: Rig) -> None:
    assert type(seed.firmware).__name__ == "Seed2025Model"
    seed.command(0.3)
    await seed.until(lambda: _moving(seed, 0.3), 4.0)
    seed.command(0.0)
    await seed.until(lambda: _still(seed), STOP_BOUND_S)
    assert seed.firmware.last_command == (0.0, 0.0)
    assert seed.firmware.rx.frames > 0
    assert seed.bridge.stats()["firmware"] == "seed-2025"


@pytest.mark.parametrize("extra", range(1, 9))
async def test_misalignment_by_k_bytes_is_repaired_and_never_wild(seed: Rig, extra: int) -> None:
    applied = _record_applied(seed)
    seed.command(0.3)
    await seed.until(lambda: _moving(seed, 0.3), 4.0)
    seed.command(0.0)
    await seed.until(lambda: _still(seed), STOP_BOUND_S)
    seed.bridge._port.write(b"\x00" * extra)  # a glitch on the line: the firmware is now misaligned
    seed.command(0.3)
    took = await seed.until(lambda: _moving(seed, 0.3), REALIGN_BOUND_S)
    assert took <= REALIGN_BOUND_S
    stats = seed.bridge.stats()
    assert 1 <= stats["realign_bytes"] <= 8, stats
    assert {(round(v, 6), round(w, 6)) for v, w in applied} <= {(0.0, 0.0), (0.3, 0.0)}  # nothing wild
    assert abs(seed.firmware.last_command[0] - 0.3) < 1e-6


async def test_a_stop_is_applied_even_while_misaligned(seed: Rig) -> None:
    seed.command(0.4)
    await seed.until(lambda: _moving(seed, 0.4), 4.0)
    seed.bridge._port.write(b"\x00" * 4)  # misaligned mid-drive: the 0.4 command keeps running
    await seed.run(0.1)
    seed.command(0.0)
    await seed.run(0.05)
    assert seed.firmware.last_command == (0.0, 0.0)  # the stop burst lands at any alignment
    await seed.until(lambda: _still(seed), STOP_BOUND_S)


async def test_a_reboot_mid_stream_is_noticed_and_driving_resumes(seed: Rig) -> None:
    events: list[Event] = []
    seed.ctx.bus.subscribe(topics.EVENTS, Event, events.append, maxsize=100)
    seed.command(0.3)
    await seed.until(lambda: _moving(seed, 0.3), 4.0)
    seed.firmware.reboot()  # the bridge keeps sending 0.3 while the MCU restarts
    await seed.until(lambda: seed.bridge.stats().get("mcu_reboots", 0) == 1, 2.0)
    await seed.until(lambda: _moving(seed, 0.3), REALIGN_BOUND_S)
    assert any(e.kind == "mcu_rebooted" and "WHO_AM_I=0x71" in e.message for e in events)


async def test_negative_theta_reaches_odom_normalised(seed: Rig) -> None:
    seed.command(0.0, -0.8)  # clockwise
    await seed.run(1.5)
    seed.command(0.0)
    await seed.run(0.5)
    await seed.settle()
    theta = seed.odom[-1].pose.theta
    assert -math.pi <= theta < 0.0
    assert theta < -0.3
    assert not seed.bridge.stats()["errors"]  # no frame rejected as implausible


async def test_no_battery_frames_means_unknown_never_zero(seed: Rig) -> None:
    await seed.run(2.5)
    await seed.settle()
    assert seed.battery, "the bridge says something about the battery"
    assert all(math.isnan(b.percentage) and math.isnan(b.voltage) for b in seed.battery)
    assert "BATTERY" not in seed.bridge.stats()["frames"]


async def test_a_byte_lost_inside_a_frame_runs_wild_and_is_stopped(seed: Rig) -> None:
    """The one harm left: the firmware applies a shifted, out-of-range command (it has no
    range check). The bridge sees odometry beyond the profile's limits, sends the stop (it
    lands) and raises an event for the operator. (The model's PI, like the firmware's, has
    no anti-windup: after a 1e30 command its integrator keeps the wheels turning long after
    the stop — the owners' firmware needs a range check; docs/mcu.md.)"""
    events: list[Event] = []
    seed.ctx.bus.subscribe(topics.EVENTS, Event, events.append, maxsize=100)
    applied = _record_applied(seed)
    seed.command(0.3)
    await seed.until(lambda: _moving(seed, 0.3), 4.0)
    frame = seed.bridge.dialect.command(0.3, 0.0)
    seed.bridge._port.write(frame[:5] + frame[6:])  # one payload byte lost on the line
    await seed.run(0.1)
    assert any(abs(w) > 1e3 for _, w in applied), "a wild command was applied (no range check)"
    align = seed.bridge.align
    assert align is not None  # the seed's dialect is block-aligned
    await seed.until(lambda: align.runaways >= 1, 2.0)
    await seed.until(lambda: seed.firmware.last_command == (0.0, 0.0), 1.0)  # the stop burst landed
    await seed.run(0.1)
    assert [e.kind for e in events].count("mcu_runaway") == 1
