"""FirmwareModel: the STM32 firmware as the simulator runs it. Pure: no I/O, no clock.

One simulation step, in order (the simulator calls them with its step ``dt``, s):

1. ``receive(data)``: bytes from the Jetson into the RX state machine (any time);
2. ``control_step(dt, now)``: watchdog, 100 Hz PI per wheel, PWM, motor model;
   returns the drive wheels' ground speeds (left, right) in m/s;
3. the world turns wheel speeds into the body's true motion (collisions included);
4. ``sense(dt, v_true, w_true)``: dead wheels (with faults), odometry, IMU, battery;
5. ``transmit(now)``: the frames due at ``now`` (ODOM + BATTERY at 50 Hz, IMU 100 Hz).
"""

from __future__ import annotations

import math
from collections import Counter

import numpy as np

from sage_robot.hardware.mcu import protocol as proto
from sage_robot.sim.firmware.deadwheel import DeadWheelOdometry, DeadWheels
from sage_robot.sim.firmware.drive import (
    STOP_EPS_MPS,
    Motor,
    WheelController,
    duty_to_pwm,
    wheel_targets,
)
from sage_robot.sim.firmware.params import (
    IMU_PERIOD_S,
    ODOM_PERIOD_S,
    PWM_STOP_US,
    EncoderFaults,
    FirmwareParams,
)
from sage_robot.sim.firmware.rx import CommandReceiver
from sage_robot.sim.firmware.sensors import Battery, ImuModel

DEFAULT_SEED = 0
SCHEDULE_EPS_S = 1e-9  # float slack when a frame is due


class FirmwareModel:
    def __init__(
        self,
        params: FirmwareParams | None = None,
        rng: np.random.Generator | None = None,
        faults: EncoderFaults | None = None,
    ) -> None:
        self.params = p = params or FirmwareParams()
        self.rng = rng if rng is not None else np.random.default_rng(DEFAULT_SEED)
        self.faults = faults or EncoderFaults()
        self.rx = CommandReceiver()
        self.wheels = DeadWheels(p, self.faults, self.rng)
        self.odometry = DeadWheelOdometry(p)
        self.battery = Battery(p, self.rng)
        self.imu = ImuModel(p, self.rng)
        self.controllers = (WheelController(p), WheelController(p))
        self.motors = (Motor(p), Motor(p))
        self._now = 0.0
        self._last_cmd_t: float | None = None
        self._cmd = (0.0, 0.0)
        self._targets = (0.0, 0.0)  # wheel speed targets after the watchdog ramp (m/s)
        self._profile = (0.0, 0.0)  # the command slewed at the body limits (v m/s, w rad/s)
        self._pwm = (PWM_STOP_US, PWM_STOP_US)
        self._duty = (0.0, 0.0)
        self._next_odom = ODOM_PERIOD_S  # first frames one period after power-up
        self._next_imu = IMU_PERIOD_S
        self.watchdog_trips = 0
        self._tripped = False
        self.frames_sent: Counter[str] = Counter()

    def set_faults(self, faults: EncoderFaults) -> None:
        """Change the dead wheels' faults (a wheel works loose mid-run)."""
        self.faults = self.wheels.faults = faults

    # ------------------------------------------------------------ read-only state
    @property
    def odom_pose(self) -> tuple[float, float, float]:
        """Firmware odometry (x m, y m, theta rad in [0, 2 pi))."""
        return self.odometry.pose

    @property
    def pwm_us(self) -> tuple[float, float]:
        """ESC pulse widths (left, right), us."""
        return self._pwm

    @property
    def wheel_speeds(self) -> tuple[float, float]:
        return (self.motors[0].speed, self.motors[1].speed)

    @property
    def battery_voltage(self) -> float:
        """The pack's true terminal voltage (V); frames carry the ADC's reading of it."""
        return self.battery.voltage

    @property
    def watchdog_tripped(self) -> bool:
        return self._tripped

    @property
    def last_command_t(self) -> float | None:
        """When the last command was received (s of the model's time), None before any."""
        return self._last_cmd_t

    @property
    def last_command(self) -> tuple[float, float]:
        """The last (v m/s, w rad/s) received and accepted."""
        return self._cmd

    # ------------------------------------------------------------ steps
    def receive(self, data: bytes) -> None:
        p = self.params
        for v, w in self.rx.feed(data, self._now):
            v = max(-p.max_cmd_v_mps, min(p.max_cmd_v_mps, v))
            w = max(-p.max_cmd_w_radps, min(p.max_cmd_w_radps, w))
            self._cmd, self._last_cmd_t, self._tripped = (v, w), self._now, False

    def control_step(self, dt: float, now: float) -> tuple[float, float]:
        p = self.params
        self._now = now
        if self._last_cmd_t is None or now - self._last_cmd_t > p.watchdog_s:
            if not self._tripped and self._last_cmd_t is not None:
                self.watchdog_trips += 1
            self._tripped = self._last_cmd_t is not None
            # Ramp toward zero instead of stopping dead.
            drop = p.watchdog_ramp_mps2 * dt
            self._targets = tuple(  # type: ignore[assignment]
                0.0 if abs(t) <= drop else t - drop * np.sign(t) for t in self._targets
            )
            left, right = self._targets
            self._profile = (0.5 * (left + right), (right - left) / p.track_width_m)
        elif self._cmd == (0.0, 0.0):
            self._targets = _brake(self._targets, p.stop_decel_mps2 * dt)
            left, right = self._targets
            self._profile = (0.5 * (left + right), (right - left) / p.track_width_m)
        else:
            v, w = self._profile
            v = _slew(v, self._cmd[0], p.cmd_accel_mps2 * dt)
            w = _slew(w, self._cmd[1], p.cmd_alpha_radps2 * dt)
            self._profile = (v, w)
            self._targets = wheel_targets(v, w, p.track_width_m)
        volt_scale = self.battery.voltage / p.nominal_voltage_v
        v_odo, w_odo = self.odometry.v_tick, self.odometry.w_tick
        measured = wheel_targets(v_odo, w_odo, p.track_width_m)
        settled = self._profile == self._cmd
        duties = tuple(
            c.step(t, m, dt, volt_scale, settled)
            for c, t, m in zip(self.controllers, self._targets, measured, strict=True)
        )
        self._duty = (float(duties[0]), float(duties[1]))
        self._pwm = (duty_to_pwm(self._duty[0]), duty_to_pwm(self._duty[1]))
        left = self.motors[0].step(self._pwm[0], dt, volt_scale)
        right = self.motors[1].step(self._pwm[1], dt, volt_scale)
        return left, right

    def sense(self, dt: float, v_true: float, w_true: float) -> None:
        ds, dh = self.wheels.roll(dt, v_true, w_true)
        self.odometry.update(ds, dh, dt)
        self.imu.step(dt, v_true, w_true)
        self.battery.step(dt, 0.5 * (abs(self._duty[0]) + abs(self._duty[1])))

    def transmit(self, now: float) -> bytes:
        self._now = max(self._now, now)
        out = bytearray()
        if now + SCHEDULE_EPS_S >= self._next_imu:
            out += self._frame(proto.IMU, self.imu.sample())
            self._next_imu = _next_due(self._next_imu, IMU_PERIOD_S, now)
        if now + SCHEDULE_EPS_S >= self._next_odom:
            o = self.odometry
            out += self._frame(proto.ODOM, (o.x, o.y, o.theta, o.v, o.w))
            out += self._frame(proto.BATTERY, (self.battery.measured_voltage(),))
            self._next_odom = _next_due(self._next_odom, ODOM_PERIOD_S, now)
        return bytes(out)

    def _frame(self, kind: proto.FrameType, values: tuple[float, ...]) -> bytes:
        self.frames_sent[kind.name] += 1
        return proto.encode(kind, values)

    @property
    def stopped(self) -> bool:
        """Both PWM outputs at stop and both wheels at rest."""
        at_rest = all(abs(s) < STOP_EPS_MPS for s in self.wheel_speeds)
        return at_rest and self._pwm == (PWM_STOP_US, PWM_STOP_US)


def _slew(value: float, goal: float, step: float) -> float:
    """``value`` moved toward ``goal`` by at most ``step``."""
    return goal if abs(goal - value) <= step else value + math.copysign(step, goal - value)


def _brake(targets: tuple[float, float], step: float) -> tuple[float, float]:
    """Wheel targets moved toward zero together: the faster wheel by ``step``, the other in
    proportion, so both reach zero at once and the curvature does not change."""
    fastest = max(abs(targets[0]), abs(targets[1]))
    if fastest <= step:
        return (0.0, 0.0)
    scale = (fastest - step) / fastest
    return (targets[0] * scale, targets[1] * scale)


def _next_due(due: float, period: float, now: float) -> float:
    """The next send time: one period on, skipping missed slots (never bunched)."""
    due += period
    if due <= now:
        due = now + period
    return due
