"""The firmware model alone (pure, no pty): odometry, watchdog, PWM, RX, battery, IMU, faults."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from sage_robot.hardware.mcu import protocol as proto
from sage_robot.sim.firmware import EncoderFaults, FirmwareModel, FirmwareParams
from sage_robot.sim.firmware.deadwheel import DeadWheelOdometry, DeadWheels
from sage_robot.sim.firmware.params import ADC_MAX_COUNTS, WATCHDOG_S
from sage_robot.sim.firmware.rx import CommandReceiver
from sage_robot.sim.firmware.sensors import Battery
from sage_robot.sim.flat_floor import FlatFloor

DT = 0.01
M_PER_COUNT = math.pi * 0.0814 / 1200  # seed: 0.0814 m dead wheel, 600 CPR x 2


class Sim:
    """The firmware model on a flat floor; ``cmd`` re-sent every 50 ms while set."""

    def __init__(self, faults: EncoderFaults | None = None, seed: int = 1, **params: Any):
        self.fw = FirmwareModel(FirmwareParams(**params), np.random.default_rng(seed), faults)
        self.floor = FlatFloor()
        self.t = 0.0
        self.k = 0
        self.cmd: tuple[float, float] | None = None
        self.decoder = proto.Decoder()
        self.frames: list[proto.Frame] = []

    def run(self, seconds: float) -> None:
        for _ in range(round(seconds / DT)):
            if self.cmd is not None and self.k % 5 == 0:
                self.fw.receive(proto.encode(proto.CMD, self.cmd))
            self.k += 1
            self.t = self.k * DT
            wheels = self.fw.control_step(DT, self.t)
            v, w = self.floor.step(DT, wheels)
            self.fw.sense(DT, v, w)
            self.frames += self.decoder.feed(self.fw.transmit(self.t))


def test_dead_wheel_geometry_is_the_seeds():
    p = FirmwareParams()
    assert p.counts_per_rev == 1200
    assert p.metres_per_count == pytest.approx(M_PER_COUNT)
    assert (p.straight_offset_y_m, p.horizontal_offset_x_m) == (0.1016, 0.400)
    wheels = DeadWheels(p, EncoderFaults(), np.random.default_rng(0))
    # Straight 1 m: the straight wheel turns 1 / (pi d) revolutions; the horizontal stays.
    ds, dh = wheels.roll(1.0, 1.0, 0.0)
    assert ds == math.floor(1.0 / M_PER_COUNT) == 4692
    assert dh == 0
    # Spin in place at 1 rad/s for 1 s: the horizontal wheel rolls w * 0.400 m; the
    # straight wheel rolls -w * 0.1016 m (it sits left of the centre).
    wheels = DeadWheels(p, EncoderFaults(), np.random.default_rng(0))
    ds, dh = wheels.roll(1.0, 0.0, 1.0)
    assert dh == math.floor(0.400 / M_PER_COUNT)
    assert ds == math.floor(-0.1016 / M_PER_COUNT)


def test_odometry_heading_from_horizontal_wheel_speed_corrected_by_turn_rate():
    p = FirmwareParams()
    odo = DeadWheelOdometry(p)
    # A quarter turn in place, in 100 ticks: counts as the wheels would see them.
    wheels = DeadWheels(p, EncoderFaults(), np.random.default_rng(0))
    for _ in range(100):
        odo.update(*wheels.roll(DT, 0.0, math.pi / 2), DT)
    assert odo.theta == pytest.approx(math.pi / 2, abs=2 * M_PER_COUNT / 0.4)
    # The straight wheel moved backwards, but corrected by the turn rate: no translation.
    assert math.hypot(odo.x, odo.y) < 2 * M_PER_COUNT


def test_theta_stays_in_zero_to_two_pi():
    s = Sim()
    s.cmd = (0.0, -1.0)  # clockwise
    s.run(2.0)
    odom = [f for f in s.frames if f.kind is proto.ODOM]
    thetas = [f.values[2] for f in odom]
    assert all(0.0 <= t < 2 * math.pi + 1e-6 for t in thetas)
    assert max(thetas) > 5.0  # it did wrap below zero to near 2 pi


def test_straight_run_reaches_the_commanded_speed_and_odometry_matches_truth():
    s = Sim()
    s.cmd = (0.5, 0.0)
    s.run(2.0)
    assert s.floor.pose[0] == pytest.approx(0.9, abs=0.1)  # accelerating costs ~0.1 m
    assert s.fw.odom_pose[0] == pytest.approx(s.floor.pose[0], abs=0.002)
    assert s.fw.wheel_speeds == pytest.approx((0.5, 0.5), abs=0.02)
    left, right = s.fw.pwm_us
    assert 1500 < left <= 1700
    assert 1500 < right <= 1700


def test_pwm_stays_in_the_esc_range_and_stop_is_1500():
    s = Sim()
    s.cmd = (1.0, 3.0)  # the firmware's own limits: far beyond the motors
    s.run(1.0)
    for pwm in s.fw.pwm_us:
        assert 1300 <= pwm <= 1700
    assert max(s.fw.pwm_us) == 1700  # saturated
    s.cmd = (0.0, 0.0)
    p = s.fw.params
    s.run(max(p.max_cmd_v_mps / p.cmd_accel_mps2, p.max_cmd_w_radps / p.cmd_alpha_radps2) + 0.05)
    assert s.fw.pwm_us == (1500.0, 1500.0)  # the profile ramped down: the ESC's stop


def test_watchdog_ramps_to_zero_after_550_ms_without_commands():
    s = Sim()
    s.cmd = (0.5, 0.0)
    s.run(1.0)
    last = s.fw.last_command_t
    assert last is not None
    s.cmd = None  # the Jetson goes silent
    s.run(last + WATCHDOG_S - s.t - 0.02)
    assert not s.fw.watchdog_tripped
    assert s.fw.pwm_us[0] > 1500
    ramp_s = 0.5 / s.fw.params.watchdog_ramp_mps2
    s.run(0.05)
    assert s.fw.watchdog_tripped
    s.run(ramp_s)
    assert s.fw.pwm_us == (1500.0, 1500.0)
    coast_s = 0.5 / s.fw.params.max_accel_mps2
    s.run(coast_s)
    assert s.fw.stopped
    assert s.fw.watchdog_trips == 1
    s.cmd = (0.2, 0.0)  # a new command clears the trip
    s.run(0.1)
    assert not s.fw.watchdog_tripped
    assert s.fw.pwm_us[0] > 1500


def test_rx_state_machine_hunts_for_sof_and_checks_type_length_and_time():
    rx = CommandReceiver()
    good = proto.encode(proto.CMD, (0.3, -0.1))
    v32, w32 = np.float32(0.3), np.float32(-0.1)
    assert rx.feed(b"\x00\x11" + good, 0.0) == [(v32, w32)]
    assert rx.feed(good[:5], 0.0) == []
    assert rx.feed(good[5:], 0.1) == [(v32, w32)]
    assert rx.feed(b"\x78" + good[1:], 0.2) == []  # 0x78 (the seed text's byte) is no SOF
    assert rx.feed(proto.encode(proto.BATTERY, (12.0,)), 0.3) == []  # not a command
    assert rx.errors["bad_type"] == 1
    assert rx.feed(bytes((0x7E, 0x01, 0x04)) + bytes(8), 0.4) == []
    assert rx.errors["bad_length"] == 1
    nan = bytes((0x7E, 0x01, 0x08)) + b"\x00\x00\xc0\x7f" + bytes(4)
    assert rx.feed(nan, 0.5) == []
    assert rx.errors["non_finite"] == 1
    rx.feed(good[:6], 1.0)  # half a frame, then 300 ms of silence: over the 200 ms timeout
    assert rx.feed(good[6:] + good, 1.3) == [(v32, w32)]
    assert rx.errors["timeout"] == 1


def test_firmware_clamps_received_commands_to_its_limits():
    fw = FirmwareModel()
    fw.receive(proto.encode(proto.CMD, (4.0, -9.0)))
    assert fw.last_command == (1.0, -3.0)


def test_frame_rates_are_50_and_100_hz():
    s = Sim()
    s.run(1.0)
    counts = s.decoder.stats.frames
    assert (counts["IMU"], counts["ODOM"], counts["BATTERY"]) == (100, 50, 50)


def test_battery_adc_chain_matches_the_seed():
    battery = Battery(FirmwareParams(adc_noise_counts=0.0), np.random.default_rng(0))
    v = battery.voltage
    pin = v / (5.545 * 0.9848)  # the calibrated factor is the true divider ratio
    assert battery.adc_counts() == round(pin / 3.3 * ADC_MAX_COUNTS)
    lsb_v = 3.3 / 4095 * 5.545 * 0.9848
    assert battery.measured_voltage() == pytest.approx(v, abs=lsb_v)


def test_battery_sags_under_motor_effort_and_discharges_faster():
    idle, busy = Sim(), Sim()
    busy.cmd = (0.8, 0.0)
    idle.run(5.0)
    busy.run(5.0)
    assert busy.fw.battery_voltage < idle.fw.battery_voltage - 0.2
    assert busy.fw.battery.charge < idle.fw.battery.charge
    volts = [f.values[0] for f in busy.frames if f.kind is proto.BATTERY]
    assert min(volts) > 12.0
    assert max(volts) < 16.8


def test_imu_has_a_constant_gyro_bias_and_noise():
    s = Sim(seed=3)
    s.run(2.0)
    gyro = np.array([f.values[:3] for f in s.frames if f.kind is proto.IMU])
    bias = s.fw.imu.gyro_bias
    assert np.abs(bias).max() > 1e-3  # a real bias
    assert gyro.mean(axis=0) == pytest.approx(bias, abs=0.001)
    assert gyro.std(axis=0) == pytest.approx([0.002] * 3, rel=0.3)
    accel = np.array([f.values[3:] for f in s.frames if f.kind is proto.IMU])
    assert accel.mean(axis=0)[2] == pytest.approx(9.80665, abs=0.01)


def test_same_seed_same_bytes():
    a, b = (
        Sim(EncoderFaults(noise_m=1e-4, straight_slip=0.02), seed=5),
        Sim(EncoderFaults(noise_m=1e-4, straight_slip=0.02), seed=5),
    )
    for s in (a, b):
        s.cmd = (0.4, 0.2)
        s.run(1.0)
    assert a.frames == b.frames


TILT_DEG = 2.0
V = 0.5


def test_tilted_horizontal_wheel_steers_the_robot_while_odometry_says_straight():
    """docs/mcu.md: a horizontal wheel tilted by b reads v sin(b) of phantom lateral travel
    on a straight run; the heading it implies, v sin(b) / x_h, is "corrected" by the PI
    loop, so the real robot turns at about -v tan(b) / x_h while /odom stays straight."""
    b = math.radians(TILT_DEG)
    s = Sim(EncoderFaults(horizontal_tilt_rad=b))
    s.cmd = (V, 0.0)
    s.run(1.0)  # up to speed
    th0 = s.floor.pose[2]
    s.run(4.0)
    true_rate = (s.floor.pose[2] - th0) / 4.0
    assert true_rate == pytest.approx(-V * math.tan(b) / 0.400, rel=0.1)
    odom_theta = math.remainder(s.fw.odom_pose[2], 2 * math.pi)
    assert abs(odom_theta) < 0.03  # the firmware believes it drives straight
    assert abs(s.floor.pose[1]) > 0.15
    assert abs(s.fw.odom_pose[1]) < 0.1  # "steers toward walls"


def test_tilted_straight_wheel_under_reads_distance_by_cos():
    a = math.radians(10.0)
    s = Sim(EncoderFaults(straight_tilt_rad=a))
    s.cmd = (V, 0.0)
    s.run(3.0)
    assert s.fw.odom_pose[0] / s.floor.pose[0] == pytest.approx(math.cos(a), rel=0.01)


def test_slip_loses_distance_and_noise_makes_heading_wobble():
    slip = Sim(EncoderFaults(straight_slip=0.05))
    slip.cmd = (V, 0.0)
    slip.run(3.0)
    assert slip.fw.odom_pose[0] / slip.floor.pose[0] == pytest.approx(0.95, abs=0.01)
    noisy = Sim(EncoderFaults(noise_m=2e-4))
    noisy.cmd = (V, 0.0)
    noisy.run(3.0)
    thetas = [math.remainder(f.values[2], 2 * math.pi) for f in noisy.frames if f.kind is proto.ODOM]
    assert np.std(thetas) > 1e-3  # wobbly


STEP_SETTLE_BAND = 0.05  # "reached": within 5 % of the command from then on
STEP_OVERSHOOT_MAX = 0.05  # at most 5 % past the command


@pytest.mark.parametrize(("cmd", "settle_s"), [((0.5, 0.0), 0.8), ((0.0, -0.8), 0.45), ((0.3, 0.5), 0.6)])
def test_step_response_reaches_the_command_quickly_without_overshoot(cmd, settle_s):
    fw = FirmwareModel(FirmwareParams(), np.random.default_rng(1))
    floor = FlatFloor()
    twists = []
    for k in range(200):  # 2 s, the command re-sent every 50 ms as the bridge does
        if k % 5 == 0:
            fw.receive(proto.encode(proto.CMD, cmd))
        wheels = fw.control_step(DT, (k + 1) * DT)
        v, w = floor.step(DT, wheels)
        fw.sense(DT, v, w)
        twists.append((v, w))
    arr = np.array(twists)
    for axis, goal in enumerate(cmd):
        if goal == 0.0:
            assert np.abs(arr[:, axis]).max() < 0.01
            continue
        off = np.nonzero(np.abs(arr[:, axis] - goal) > STEP_SETTLE_BAND * abs(goal))[0]
        assert (off[-1] + 1) * DT <= settle_s, f"axis {axis} settles at {(off[-1] + 1) * DT} s"
        assert np.abs(arr[:, axis]).max() <= abs(goal) * (1 + STEP_OVERSHOOT_MAX)


def test_a_timed_quarter_turn_turns_a_quarter():
    """Forward, a timed 90 deg turn, forward again (the teleop scenario): the heading the
    robot ends with is the commanded one. The wheel that changes speed most must not
    saturate longer at the end of the turn than at its start (once ~8 deg too far)."""
    fw = FirmwareModel(FirmwareParams(), np.random.default_rng(1))
    floor = FlatFloor()
    turn_s = 1.96
    plan = [(0.0, (0.4, 0.0)), (3.0, (0.0, -0.8)), (3.0 + turn_s, (0.6, 0.0))]
    cmd = plan[0][1]
    for k in range(800):
        t = k * DT
        for at, c in plan:
            if abs(t - at) < DT / 2:
                cmd = c
                fw.receive(proto.encode(proto.CMD, cmd))  # the bridge writes on every change
        if k % 5 == 0:
            fw.receive(proto.encode(proto.CMD, cmd))
        v, w = floor.step(DT, fw.control_step(DT, t + DT))
        fw.sense(DT, v, w)
    assert math.degrees(floor.pose[2]) == pytest.approx(math.degrees(-0.8 * turn_s), abs=0.5)
    assert floor.pose[0] == pytest.approx(0.4 * 3.0, abs=0.1)  # ideal: 1.2 m east
