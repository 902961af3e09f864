"""Seed2025Model: the firmware the seed robot's STM32 runs today ("seed-2025"), as the
simulator runs it. Pure: no I/O, no clock. Same stepping as :class:`FirmwareModel`:

1. ``receive(data)``: Jetson bytes into the fixed 9-byte block reception (``blockrx``);
   a block starting with 0x78 is applied at once, raw: no range check, no finite check;
2. ``control_step(dt, now)``: the firmware's own 100 Hz tick (encoders -> odometry and
   wheel speeds -> PI -> ESC pulses), then the motors for ``dt``; returns the drive
   wheels' ground speeds (left, right) in m/s;
3. the world turns wheel speeds into the body's true motion;
4. ``sense(dt, v_true, w_true)``: the encoders count the wheels' rotation; IMU; battery;
5. ``transmit(now)``: the boot banner once, then ODOM (50 Hz) and IMU (100 Hz) frames.

No command watchdog: the last accepted command runs until another replaces it (or a
:meth:`reboot`). No BATTERY frame is ever sent. ODOM theta is ``fmodf(theta, 2 pi)``.
See docs/sim.md, "seed-2025 firmware model".
"""

from __future__ import annotations

import math
from collections import Counter

import numpy as np

from sage_robot.hardware.mcu import protocol as proto
from sage_robot.sim.firmware.blockrx import BlockReceiver
from sage_robot.sim.firmware.drive import STOP_EPS_MPS, wheel_targets
from sage_robot.sim.firmware.encoders import EncoderOdometry, MotorEncoders
from sage_robot.sim.firmware.esc import EscMotor, SpeedPI, esc_pulse, pulse_is_coasting
from sage_robot.sim.firmware.seed2025_params import (
    ESC_NEUTRAL_US,
    SEED_BANNER,
    SEED_IMU_PERIOD_S,
    SEED_ODOM_PERIOD_S,
    Seed2025Params,
)
from sage_robot.sim.firmware.sensors import Battery, ImuModel

DEFAULT_SEED = 0
SCHEDULE_EPS_S = 1e-9  # float slack when a tick or a frame is due
MAX_CATCH_UP_TICKS = 10  # control ticks run at most per call; further behind: resync
BANNER_KEY = "BANNER"  # frames_sent key of the boot banner


class Seed2025Model:
    def __init__(self, params: Seed2025Params | None = None, rng: np.random.Generator | None = None) -> None:
        self.params = p = params or Seed2025Params()
        self.rng = rng if rng is not None else np.random.default_rng(DEFAULT_SEED)
        sensors = p.sensor_params()
        self.battery = Battery(sensors, self.rng)
        self.imu = ImuModel(sensors, self.rng)
        self.rx = BlockReceiver()
        self.encoders = MotorEncoders(p.metres_per_count)
        self.odometry = EncoderOdometry(p)
        self.controllers = (SpeedPI(p), SpeedPI(p))
        self.motors = (EscMotor(p), EscMotor(p))
        self.frames_sent: Counter[str] = Counter()
        self.watchdog_trips = 0  # there is no watchdog: always 0
        self.reboots = 0
        self.non_finite_commands = 0  # applied commands holding NaN or inf
        self._now = 0.0
        self._boot()

    def _boot(self) -> None:
        """Power-up or reset: everything the MCU keeps in RAM starts over."""
        now = self._now
        self._cmd = (0.0, 0.0)
        self._last_cmd_t: float | None = None
        for c in self.controllers:
            c.reset()
        self._pwm = (ESC_NEUTRAL_US, ESC_NEUTRAL_US)
        self.odometry.reset(self.encoders.counts)
        self.rx.rearm()
        self._tx = bytearray(SEED_BANNER)
        self.frames_sent[BANNER_KEY] += 1
        p = self.params
        self._next_tick = now + p.control_period_s
        self._next_odom = now + SEED_ODOM_PERIOD_S  # first frames one period after boot
        self._next_imu = now + SEED_IMU_PERIOD_S

    def reboot(self) -> None:
        """The MCU resets: odometry to zero, command cleared (it stops), 9-byte reception
        re-armed (bytes arriving next start a new block: a partial block is lost and the
        stream may be misaligned from then on), the banner sent again. The wheels keep
        their momentum; the fresh PI brakes them toward the zero command."""
        self.reboots += 1
        self._boot()

    # ------------------------------------------------------------ read-only state
    @property
    def odom_pose(self) -> tuple[float, float, float]:
        """Firmware odometry (x m, y m, theta rad in (-2 pi, 2 pi)), float32 values."""
        return self.odometry.pose

    @property
    def pwm_us(self) -> tuple[float, float]:
        """ESC pulse widths (left, right), us; 0 = no pulse (a NaN reached the timer)."""
        return self._pwm

    @property
    def pi_output(self) -> tuple[float, float]:
        """The PI outputs u (left, right), m/s, the pulses were made from."""
        return (self.controllers[0].output, self.controllers[1].output)

    @property
    def wheel_speeds(self) -> tuple[float, float]:
        return (self.motors[0].speed, self.motors[1].speed)

    @property
    def battery_voltage(self) -> float:
        """The pack's true terminal voltage (V); the firmware never reports it."""
        return self.battery.voltage

    @property
    def watchdog_tripped(self) -> bool:
        return False  # no watchdog in seed-2025

    @property
    def last_command_t(self) -> float | None:
        """When the last command was applied (s of the model's time); None since boot."""
        return self._last_cmd_t

    @property
    def last_command(self) -> tuple[float, float]:
        """The last (v m/s, w rad/s) applied, raw (float32 values, possibly NaN or inf)."""
        return self._cmd

    @property
    def stopped(self) -> bool:
        """Both ESCs not driven (neutral or no pulse) and both wheels at rest."""
        at_rest = all(abs(s) < STOP_EPS_MPS for s in self.wheel_speeds)
        return at_rest and all(pulse_is_coasting(x) for x in self._pwm)

    # ------------------------------------------------------------ steps
    def receive(self, data: bytes) -> None:
        for v, w in self.rx.feed(data):
            if not (math.isfinite(v) and math.isfinite(w)):
                self.non_finite_commands += 1
            self._cmd, self._last_cmd_t = (v, w), self._now

    def control_step(self, dt: float, now: float) -> tuple[float, float]:
        self._now = now
        period = self.params.control_period_s
        ticks = 0
        while now + SCHEDULE_EPS_S >= self._next_tick:
            if ticks == MAX_CATCH_UP_TICKS:  # far behind (a stalled caller): no burst
                self._next_tick = now + period
                break
            self._tick(period)
            self._next_tick += period
            ticks += 1
        left = self.motors[0].step(self._pwm[0], dt)
        right = self.motors[1].step(self._pwm[1], dt)
        return left, right

    def _tick(self, period: float) -> None:
        """One 100 Hz firmware tick: encoders, odometry, PI, ESC compare registers."""
        self.odometry.update(self.encoders.counts, period)
        targets = wheel_targets(self._cmd[0], self._cmd[1], self.params.track_width_m)
        measured = self.odometry.wheel_speeds
        u = [c.step(t, m, period) for c, t, m in zip(self.controllers, targets, measured, strict=True)]
        self._pwm = (esc_pulse(u[0]), esc_pulse(u[1]))

    def sense(self, dt: float, v_true: float, w_true: float) -> None:
        """The encoders count the wheels' own rotation (not ``v_true``/``w_true``: a wheel
        that spins against a wall still counts); the IMU feels the body's true motion."""
        self.encoders.roll(dt, *self.wheel_speeds)
        self.imu.step(dt, v_true, w_true)
        effort = 0.5 * sum(abs(m.goal(x)) for m, x in zip(self.motors, self._pwm, strict=True))
        self.battery.step(dt, effort)

    def transmit(self, now: float) -> bytes:
        self._now = max(self._now, now)
        out, self._tx = self._tx, bytearray()
        if now + SCHEDULE_EPS_S >= self._next_imu:
            out += self._frame(proto.IMU, self.imu.sample())
            self._next_imu = _next_due(self._next_imu, SEED_IMU_PERIOD_S, now)
        if now + SCHEDULE_EPS_S >= self._next_odom:
            o = self.odometry
            out += self._frame(proto.ODOM, (o.x, o.y, o.theta, o.v, o.w))
            self._next_odom = _next_due(self._next_odom, SEED_ODOM_PERIOD_S, now)
        return bytes(out)

    def _frame(self, kind: proto.FrameType, values: tuple[float, ...]) -> bytes:
        self.frames_sent[kind.name] += 1
        return proto.encode(kind, values)


def _next_due(due: float, period: float, now: float) -> float:
    """The next send time: one period on, skipping missed slots (never bunched)."""
    due += period
    if due <= now:
        due = now + period
    return due
