"""Motor drive: the 100 Hz PI loop per wheel, ESC-style PWM and the motor/chassis model.

Each wheel's target ground speed comes from the command (v, w) by differential-drive
kinematics, ``v_l = v - w Lw / 2``, ``v_r = v + w Lw / 2``. Feedback is the wheel speed
that the dead-wheel odometry implies (the STM32 has no motor encoders), so an encoder
fault steers the real robot. The PI output is a duty in [-1, 1] mapped to a pulse width
``1500 + 200 * duty`` us (1300..1700). A duty of zero is the ESC's stop.

Motor + chassis: each wheel's ground speed follows ``duty * free_speed * V / V_nominal``
with time constant ``motor_tau_s``, acceleration limited to ``max_accel_mps2``; at
PWM stop the wheel coasts down at ``friction_decel_mps2`` on top of the lag.
"""

from __future__ import annotations

import math

from sage_robot.sim.firmware.params import PWM_SPAN_US, PWM_STOP_US, FirmwareParams

STOP_EPS_MPS = 1e-4  # a target below this is a stop: PWM 1500, integrator cleared


class WheelController:
    """PI on one wheel's ground speed; output duty in [-1, 1]."""

    def __init__(self, params: FirmwareParams) -> None:
        self.p = params
        self.integral = 0.0  # duty
        self.measured = 0.0  # filtered measured speed (m/s)

    def step(
        self, target: float, measured: float, dt: float, volt_scale: float, integrate: bool = True
    ) -> float:
        """``integrate`` False while the target is still ramping: the motor's lag behind a
        ramp is no steady error, and integrating it winds up into overshoot."""
        p = self.p
        self.measured += p.speed_filter_alpha * (measured - self.measured)
        if abs(target) < STOP_EPS_MPS:
            self.integral = 0.0
            return 0.0
        error = target - self.measured
        if integrate and abs(error) < p.integrate_band_mps:  # conditional integration
            self.integral += p.ki_duty_per_m * error * dt
        self.integral = max(-p.integral_limit_duty, min(p.integral_limit_duty, self.integral))
        feedforward = target / (p.free_speed_mps * max(volt_scale, 1e-3))
        duty = feedforward + p.kp_duty_per_mps * error + self.integral
        return max(-1.0, min(1.0, duty))


def duty_to_pwm(duty: float) -> float:
    """Duty in [-1, 1] -> ESC pulse width in us (1300..1700, 1500 = stop)."""
    return PWM_STOP_US + PWM_SPAN_US * max(-1.0, min(1.0, duty))


def pwm_to_duty(pwm_us: float) -> float:
    return max(-1.0, min(1.0, (pwm_us - PWM_STOP_US) / PWM_SPAN_US))


class Motor:
    """One drive wheel's motor and its share of the chassis inertia."""

    def __init__(self, params: FirmwareParams) -> None:
        self.p = params
        self.speed = 0.0  # wheel ground speed (m/s)

    def step(self, pwm_us: float, dt: float, volt_scale: float) -> float:
        p = self.p
        duty = pwm_to_duty(pwm_us)
        goal = duty * p.free_speed_mps * volt_scale
        accel = (goal - self.speed) / p.motor_tau_s
        accel = max(-p.max_accel_mps2, min(p.max_accel_mps2, accel))
        new = self.speed + accel * dt
        if duty == 0.0:
            # Coasting: friction brings the wheel to rest instead of an endless decay.
            drop = p.friction_decel_mps2 * dt
            new = 0.0 if abs(new) <= drop else new - math.copysign(drop, new)
        self.speed = new
        return new


def wheel_targets(v: float, w: float, track_width_m: float) -> tuple[float, float]:
    """Body (v, w) -> (left, right) wheel ground speeds."""
    half = 0.5 * track_width_m
    return v - w * half, v + w * half
