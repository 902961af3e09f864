"""The seed-2025 drive: 100 Hz PI per wheel, the coarse ESC pulse mapping, the motor lag.

PI (per wheel, on ground speed in m/s): ``e = target - measured``, ``I += KI e dt``,
``u = KP e + I``. No feed-forward, no reset on a zero target (a plain PI, as the facts
give it); the output ``u`` (m/s) becomes a pulse ``1500 + 70 u`` us; a pulse above
1600 us becomes 1750 us, below 1400 us 1250 us, anything in between is rounded to the
timer's 1 us. So the ESC only ever sees 1400..1600 us or one of the two steps, and a speed
the linear band cannot reach (above 0.4 m/s) is held by the PI dithering between
<= 1600 us and 1750 us.

Non-finite values propagate as they would in the C code: a NaN target makes ``I`` NaN for
good (until a reboot), the pulse NaN, which the timer's compare register receives as 0:
no pulse, and the ESC's signal-loss failsafe stops driving (the wheel coasts to rest). An
infinite target saturates the pulse at a step (1750 or 1250 us) and leaves ``I`` infinite,
so that wheel keeps going until a reboot (or until an opposite infinity makes it NaN).

Motor + chassis: the wheel's ground speed follows ``(pulse - 1500) x esc_mps_per_us``
with time constant ``motor_tau_s``, acceleration limited to ``max_accel_mps2``; at
neutral or with no pulse it coasts and friction brings it to rest.
"""

from __future__ import annotations

import math

from sage_robot.sim.firmware.seed2025_params import (
    ESC_LINEAR_HIGH_US,
    ESC_LINEAR_LOW_US,
    ESC_NEUTRAL_US,
    ESC_NO_PULSE_US,
    ESC_STEP_HIGH_US,
    ESC_STEP_LOW_US,
    ESC_TICK_US,
    ESC_US_PER_MPS,
    Seed2025Params,
)


def esc_pulse(u: float) -> float:
    """PI output ``u`` (m/s) -> the pulse width the timer outputs (us); 0 = no pulse."""
    pulse = ESC_NEUTRAL_US + ESC_US_PER_MPS * u
    if math.isnan(pulse):
        return ESC_NO_PULSE_US
    if pulse > ESC_LINEAR_HIGH_US:
        return ESC_STEP_HIGH_US
    if pulse < ESC_LINEAR_LOW_US:
        return ESC_STEP_LOW_US
    return round(pulse / ESC_TICK_US) * ESC_TICK_US


def pulse_is_coasting(pulse_us: float) -> bool:
    """Neutral, or no pulse at all (the ESC's failsafe): the motor is not driven."""
    return pulse_us in (ESC_NEUTRAL_US, ESC_NO_PULSE_US)


class SpeedPI:
    """The firmware's PI on one wheel's ground speed; output in m/s (see module doc)."""

    def __init__(self, params: Seed2025Params) -> None:
        self.p = params
        self.integral = 0.0  # m/s
        self.output = 0.0  # u, m/s

    def step(self, target: float, measured: float, dt: float) -> float:
        p = self.p
        error = target - measured
        self.integral += p.ki_per_s * error * dt
        limit = p.integral_limit_mps
        if limit is not None and not math.isnan(self.integral):
            self.integral = max(-limit, min(limit, self.integral))
        self.output = p.kp * error + self.integral
        return self.output

    def reset(self) -> None:
        self.integral = self.output = 0.0


class EscMotor:
    """One drive wheel: ESC, motor and its share of the chassis inertia."""

    def __init__(self, params: Seed2025Params) -> None:
        self.p = params
        self.speed = 0.0  # wheel ground speed (m/s)

    def goal(self, pulse_us: float) -> float:
        """The steady ground speed a pulse gives (m/s); 0 when not driven."""
        if pulse_is_coasting(pulse_us):
            return 0.0
        return (pulse_us - ESC_NEUTRAL_US) * self.p.esc_mps_per_us

    def step(self, pulse_us: float, dt: float) -> float:
        p = self.p
        accel = (self.goal(pulse_us) - self.speed) / p.motor_tau_s
        accel = max(-p.max_accel_mps2, min(p.max_accel_mps2, accel))
        new = self.speed + accel * dt
        if pulse_is_coasting(pulse_us):
            drop = p.friction_decel_mps2 * dt
            new = 0.0 if abs(new) <= drop else new - math.copysign(drop, new)
        self.speed = new
        return new
