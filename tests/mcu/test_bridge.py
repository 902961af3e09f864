"""End to end over a real pseudo-terminal: the serial bridge node <-> the firmware model,
on the simulated clock (tests/mcu/rig.py)."""

from __future__ import annotations

import asyncio
import logging
import math
from typing import Any, cast

import pytest

from sage_robot.app.launcher import NodeSpec
from sage_robot.app.profiles import PROFILES
from sage_robot.app.registry import node_class
from sage_robot.app.runtime import SIM_STEP_S, make_context, run_launcher
from sage_robot.core import topics
from sage_robot.core.config import load_profile
from sage_robot.core.msgs import Event, Level
from sage_robot.hardware.mcu import protocol as proto
from sage_robot.hardware.mcu.bridge import BATTERY_PUBLISH_PERIOD_S, PORT_RESOURCE
from sage_robot.sim.firmware import EncoderFaults

from .rig import Rig, close_rig, make_rig


async def test_half_a_metre_per_second_for_two_seconds_is_about_a_metre(rig: Rig):
    rig.command(0.5)
    await rig.run(2.0)
    rig.command(0.0)
    await rig.run(0.5)
    await rig.settle()
    last = rig.odom[-1]
    assert last.pose.x == pytest.approx(1.0, abs=0.1)
    assert last.pose.x == pytest.approx(rig.sim.floor.pose[0], abs=0.01)
    assert abs(last.pose.y) < 1e-3
    assert -math.pi <= last.pose.theta < math.pi
    assert (last.frame_id, last.child_frame_id) == ("odom", "base_link")
    assert last.pose_covariance[0] > 0
    assert last.twist_covariance[8] > 0
    assert max(o.twist.linear_x for o in rig.odom) == pytest.approx(0.5, abs=0.05)
    stats = rig.bridge.stats()
    assert stats["frames"]["ODOM"] == len(rig.odom)
    assert not stats["errors"]


async def test_stop_brings_the_motors_to_zero_within_the_watchdog_plus_ramp(rig: Rig):
    rig.command(0.5)
    await rig.run(1.5)
    pwm_moving = rig.firmware.pwm_us
    rig.command(0.0)
    await rig.run(0.03)  # bridge writes; next tick the firmware reads; the one after acts
    assert rig.firmware.last_command == (0.0, 0.0)
    assert all(now < before for now, before in zip(rig.firmware.pwm_us, pwm_moving, strict=True))
    p = rig.firmware.params
    # A stop brakes at stop_decel_mps2 (the emergency deceleration); the motors lag it.
    bound = 0.5 / p.stop_decel_mps2 + 0.5 / p.max_accel_mps2
    await rig.until(lambda: rig.firmware.stopped, bound)
    assert rig.firmware.pwm_us == (1500.0, 1500.0)


async def test_a_dead_jetson_trips_the_watchdog(rig: Rig):
    rig.command(0.5)
    await rig.run(1.5)
    # The bridge process dies without a word: its port closes, no stop frame is sent.
    await rig.bridge._close()
    rig.bridge._close_port()
    last = rig.firmware.last_command_t
    p = rig.firmware.params
    await rig.run(p.watchdog_s - 0.05)
    assert not rig.firmware.watchdog_tripped
    assert rig.firmware.wheel_speeds[0] > 0.4
    took = await rig.until(lambda: rig.firmware.stopped, 0.5 / p.watchdog_ramp_mps2 + 0.6)
    assert rig.firmware.watchdog_tripped
    assert rig.clock.now() - last <= p.watchdog_s + 0.5 / p.watchdog_ramp_mps2 + 0.5
    assert took > 0


async def test_reverse_commands_never_drive_backwards(rig: Rig):
    rig.command(-0.4)
    await rig.run(1.0)
    assert rig.firmware.last_command == (0.0, 0.0)
    assert min(rig.firmware.pwm_us) == 1500.0
    assert rig.sim.floor.pose[0] == 0.0
    rig.command(-0.4, 0.5)  # a turn in place is still allowed
    await rig.run(1.0)
    await rig.settle()
    assert rig.firmware.last_command[0] == 0.0
    assert rig.firmware.last_command[1] > 0
    assert rig.odom[-1].pose.theta > 0.2
    assert math.hypot(*rig.sim.floor.pose[:2]) < 0.01
    assert rig.bridge.stats()["cmd_clamped"] >= 2  # both commands (each repeat counts too)


async def test_commands_are_clamped_to_the_profile_limits(rig: Rig):
    rig.command(5.0, -9.0)
    await rig.run(0.03)
    v, w = rig.firmware.last_command
    assert (v, w) == pytest.approx((0.8, -1.0))  # robot.max_linear_mps / max_angular_radps


async def test_a_standing_command_is_resent_at_resend_hz_and_never_trips(rig: Rig):
    rig.command(0.3)
    received0 = rig.firmware.rx.frames
    await rig.run(2.0)
    assert rig.firmware.rx.frames - received0 >= 2.0 * 10  # >= 10 Hz
    assert rig.firmware.watchdog_trips == 0
    assert rig.firmware.wheel_speeds[0] == pytest.approx(0.3, abs=0.02)


async def test_the_simulated_mcu_marks_its_clock_idle_only_at_rest(rig: Rig):
    """The simulator's process wakes less while nothing is commanded and nothing moves
    (process groups: the clock's idle_steps_per_wake); a command ends that at once."""
    await rig.run(0.1)
    assert rig.clock.idle
    rig.command(0.3)
    await rig.run(0.05)
    assert not rig.clock.idle
    rig.command(0.0)
    await rig.until(lambda: rig.firmware.stopped, 3.0)
    await rig.run(SIM_STEP_S)
    assert rig.clock.idle


async def test_command_timeout_stops_a_stale_command():
    rig = await make_rig({"mcu": {"cmd_timeout_s": 0.5}})
    try:
        rig.command(0.3)
        await rig.run(0.4)
        rig.go_silent()  # the publisher dies: its last command stands on the bus
        last_publish = rig.held_t
        await rig.run(0.3)
        assert rig.firmware.last_command[0] > 0  # 0.3 s of silence < 0.5 s timeout
        took = await rig.until(lambda: rig.firmware.last_command == (0.0, 0.0), 1.0)
        silent = rig.clock.now() - last_publish
        assert 0.5 <= silent <= 0.5 + 0.05, f"zero on the wire {silent:.3f} s after the last command"
        assert took > 0
        assert rig.bridge.stats()["cmd_timeouts"] == 1
    finally:
        await close_rig(rig)


async def test_default_command_timeout_puts_zero_on_the_wire_within_0_3_s(rig: Rig):
    """The bridge's own dead-man is on by default: a publisher that goes silent mid-drive
    is stopped on the wire <= 0.3 s after its last command, and the firmware model brakes
    to rest from 0.5 m/s within 0.6 s of that stop."""
    rig.command(0.5)
    await rig.run(2.0)
    rig.go_silent()
    last_publish = rig.held_t
    await rig.until(lambda: rig.firmware.last_command == (0.0, 0.0), 1.0)
    zero_after = rig.clock.now() - last_publish
    assert zero_after <= 0.3, f"zero on the wire {zero_after:.3f} s after the last command"
    at_rest = await rig.until(lambda: rig.firmware.stopped, 1.0)
    assert at_rest <= 0.6, f"at rest {at_rest:.3f} s after the stop"


async def test_shutdown_sends_a_stop(rig: Rig):
    rig.command(0.3)
    await rig.run(0.5)
    await rig.bridge._close()
    await rig.bridge.teardown()
    rig.sim.pty.pump(rig.clock.now())
    assert rig.firmware.last_command == (0.0, 0.0)


async def test_battery_state_carries_voltage_and_percentage(rig: Rig):
    await rig.run(0.5)
    await rig.settle()
    last = rig.battery[-1]
    assert last.voltage == pytest.approx(rig.firmware.battery_voltage, abs=0.05)
    curve = rig.ctx.settings.battery.discharge_curve
    volts, charge = zip(*curve, strict=True)
    import numpy as np

    assert last.percentage == pytest.approx(float(np.interp(last.voltage, volts, charge)))
    assert 0.0 < last.percentage < 1.0
    assert rig.bridge.stats()["frames_per_s"] == {}  # no status period elapsed yet
    await rig.run(1.0)
    await rig.settle()
    rates = rig.bridge.stats()["frames_per_s"]
    # On the SimClock the bridge reads at fixed simulated times: exact but for the window's edges.
    assert rates["ODOM"] == pytest.approx(50, abs=1)
    assert rates["IMU"] == pytest.approx(100, abs=2)


async def test_bad_frames_on_the_wire_are_counted_and_dropped(rig: Rig):
    import struct

    await rig.run(0.2)
    await rig.settle()
    bad = (
        b"\x13\x37\x00"  # line noise without a SOF
        + bytes((0x7E, 0x02, 0x10)) + bytes(16)  # ODOM with LEN 16
        + bytes((0x7E, 0x04, 0x04)) + struct.pack("<f", math.nan)  # NaN battery
        + bytes((0x7E, 0x09, 0x04)) + bytes(4)  # unknown type
        + bytes((0x7E, 0x04, 0x04)) + struct.pack("<f", 500.0)  # 500 V battery
    )  # fmt: skip
    before = rig.bridge.stats()
    n_battery = len(rig.battery)
    rig.sim.pty.inject(bad)
    await rig.run(BATTERY_PUBLISH_PERIOD_S + 0.1)  # one more /battery_state is due
    await rig.settle()
    after = rig.bridge.stats()
    assert after["bytes_dropped"] - before["bytes_dropped"] == len(bad)
    assert after["errors"] == {
        "bad_length": 1,
        "non_finite": 1,
        "unknown_type": 1,
        "implausible": 1,
    }
    assert all(b.voltage < 20 for b in rig.battery[n_battery:])  # nothing bogus published
    assert len(rig.battery) > n_battery  # and the link kept working


async def test_unplug_and_replug_are_survived(rig: Rig, caplog: pytest.LogCaptureFixture):
    caplog.set_level(logging.INFO, logger="sage.serial_bridge")
    events: list[Event] = []
    rig.ctx.bus.subscribe(topics.EVENTS, Event, events.append)
    rig.command(0.3)
    await rig.run(0.5)
    rig.sim.pty.unplug()
    await rig.until(lambda: not rig.bridge.connected, 3.0)
    await rig.run(2.0)  # several reopen attempts, all failing
    lost = [r for r in caplog.records if "link lost" in r.getMessage()]
    assert len(lost) == 1
    assert lost[0].levelno == logging.WARNING  # one clear line
    assert [r for r in caplog.records if r.levelno >= logging.ERROR] == []
    down = [s for s in rig.status if s.level is Level.ERROR]
    assert down
    assert "disconnected" in down[-1].message
    assert len(down) >= 2  # published while disconnected, not once
    assert rig.firmware.stopped  # no commands arrive: the MCU's watchdog stopped it
    n_odom = len(rig.odom)
    rig.sim.pty.replug()
    await rig.until(lambda: rig.bridge.connected, 2 * rig.ctx.settings.mcu.reconnect_s)
    rig.command(0.3)
    await rig.run(1.0)
    await rig.settle()
    assert len(rig.odom) > n_odom
    assert rig.firmware.wheel_speeds[0] == pytest.approx(0.3, abs=0.03)
    stats = rig.bridge.stats()
    assert stats["connected"]
    assert stats["reconnects"] == 1
    assert stats["disconnects"] == 1
    assert rig.status[-1].level is Level.OK
    assert [e.kind for e in events] == ["mcu_disconnected", "mcu_reconnected"]


async def test_tilted_dead_wheel_shows_the_documented_drift(rig: Rig):
    tilt = math.radians(2.0)
    rig.firmware.set_faults(EncoderFaults(horizontal_tilt_rad=tilt))
    rig.command(0.5)
    await rig.run(1.0)
    th0 = rig.sim.floor.pose[2]
    await rig.run(4.0)
    await rig.settle()
    true_rate = (rig.sim.floor.pose[2] - th0) / 4.0
    assert true_rate == pytest.approx(-0.5 * math.tan(tilt) / 0.400, rel=0.1)
    assert abs(rig.odom[-1].pose.theta) < 0.03  # /odom believes it drives straight
    assert abs(rig.sim.floor.pose[1]) > 0.15
    assert abs(rig.odom[-1].pose.y) < 0.1


async def test_imu_calibration_waits_for_stillness_and_removes_the_bias(
    caplog: pytest.LogCaptureFixture,
):
    caplog.set_level(logging.INFO, logger="sage.serial_bridge")
    rig = await make_rig({"mcu": {"imu_enabled": True, "imu_calibration_s": 2.0}})
    try:
        await rig.run(0.5)
        rig.command(0.0, 0.8)  # someone turns the robot during calibration
        await rig.run(0.5)
        rig.command(0.0)
        await rig.run(1.0)
        await rig.settle()
        assert not rig.imu
        assert not rig.bridge.stats()["imu_calibrated"]
        assert any("moved during IMU calibration" in r.getMessage() for r in caplog.records)
        await rig.run(2.5)
        await rig.settle()
        assert rig.bridge.stats()["imu_calibrated"]
        assert rig.imu
        bias = rig.firmware.imu.gyro_bias
        assert rig.bridge.calibrator is not None
        assert rig.bridge.calibrator.bias is not None
        assert rig.bridge.calibrator.bias == pytest.approx(tuple(bias), abs=0.002)
        gz = [m.angular_velocity[2] for m in rig.imu]
        assert abs(sum(gz) / len(gz)) < 0.002  # bias removed
        rig.command(0.0, 0.5)
        await rig.run(1.0)
        await rig.settle()
        assert rig.imu[-1].angular_velocity[2] == pytest.approx(0.5, abs=0.03)
    finally:
        await close_rig(rig)


async def test_sim_profile_wires_mcu_sim_and_serial_bridge():
    """The registry names, the profiles' order, and the two nodes under the launcher."""
    sim = PROFILES["sim"]
    assert sim.index(("mcu_sim", True)) < sim.index(("serial_bridge", True))
    assert ("serial_bridge", True) in PROFILES["tour"]
    settings = load_profile(None, {"sim": {"speed": None}})
    ctx = make_context(settings, simulated=True)
    specs = [NodeSpec(n, node_class(n), True) for n in ("mcu_sim", "serial_bridge")]
    launcher = await asyncio.wait_for(run_launcher(ctx, specs, until=2.0), 60)
    report = launcher.health_report()
    assert report["mcu_sim"]["restarts"] == 0
    assert report["serial_bridge"]["restarts"] == 0
    assert cast(dict[str, Any], report["serial_bridge"]["stats"])["frames"].get("ODOM", 0) > 0
    assert proto.ODOM.name in cast(dict[str, Any], report["mcu_sim"]["stats"])["frames_sent"]
    assert PORT_RESOURCE not in ctx.resources  # the simulated MCU cleaned up after itself


async def test_battery_percentage_does_not_swing_with_the_motor_load(rig: Rig):
    await rig.run(0.5)
    await rig.settle()
    at_rest = rig.battery[-1]
    rig.command(0.8)
    await rig.run(6.0)
    await rig.settle()
    raw = rig.bridge.stats()["battery_raw_v"]
    assert raw < at_rest.voltage - 0.3  # the pack really sags under the motors
    driving = rig.battery[-1]
    # 6 s of a 30 s average: well inside a watchdog's 3 % hysteresis.
    assert abs(driving.percentage - at_rest.percentage) < 0.02, (at_rest, driving, raw)
