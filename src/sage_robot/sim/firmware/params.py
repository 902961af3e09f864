"""Constants of the STM32 firmware and of the robot it drives (seed section 6).

Units are SI. Frames: x forward, y left, theta counter-clockwise (REP 103).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

# ---------------------------------------------------------------- seed constants
CTRL_HZ = 100.0  # control loop rate (Hz)
TRACK_WIDTH_M = 0.381  # Lw, wheel-to-wheel
DW_ENCODER_CPR = 600  # counts per revolution in 1x mode
DW_COUNTS_PER_REV = DW_ENCODER_CPR * 2  # 2x decoding: 1200 counts/rev
DW_WHEEL_DIAMETER_M = 0.0814  # dead wheel effective diameter (calibrated)
DW_S_OFFSET_Y_M = 0.1016  # straight dead wheel: lateral offset from centre (left +)
DW_H_OFFSET_X_M = 0.400  # horizontal dead wheel: forward offset from centre
WATCHDOG_S = 0.55  # no command for this long -> ramp the motors to zero
RX_TIMEOUT_S = 0.2  # a started frame must complete within this
PWM_STOP_US = 1500.0  # ESC pulse width meaning stop
PWM_SPAN_US = 200.0  # 1300..1700 us: full reverse .. full forward
ODOM_PERIOD_S = 0.02  # ODOM and BATTERY at 50 Hz
IMU_PERIOD_S = 0.01  # IMU at 100 Hz

# Battery ADC on PA4: divider 100 ohm over 22 ohm, 12-bit ADC at 3.3 V full scale.
DIVIDER_TOP_OHM = 100.0
DIVIDER_BOTTOM_OHM = 22.0
ADC_VREF_V = 3.3
ADC_MAX_COUNTS = 4095
ADC_FACTOR = 5.545  # ~ (100 + 22) / 22, the firmware's conversion factor
ADC_CALIBRATION = 0.9848  # the firmware's calibration multiplier

GRAVITY_MPS2 = 9.80665

# 4S Li-ion open-circuit voltage against state of charge (charge 0..1, volts).
DEFAULT_OCV_CURVE: tuple[tuple[float, float], ...] = (
    (0.0, 12.0),
    (0.1, 13.2),
    (0.3, 14.0),
    (0.6, 14.8),
    (0.85, 15.6),
    (1.0, 16.8),
)


@dataclass(frozen=True)
class FirmwareParams:
    """Everything the firmware model needs. Defaults describe the seed's robot."""

    track_width_m: float = TRACK_WIDTH_M
    # Drive: a first-order motor+chassis lag toward duty x free speed, with limits.
    free_speed_mps: float = 1.0  # ground speed of a wheel at full duty and nominal voltage
    nominal_voltage_v: float = 14.8
    motor_tau_s: float = 0.15  # time constant of wheel speed (motor + chassis inertia)
    max_accel_mps2: float = 1.5  # traction / current limit on wheel acceleration
    friction_decel_mps2: float = 0.3  # coasting deceleration at PWM stop
    # PI on each wheel's speed as measured by the dead-wheel odometry.
    kp_duty_per_mps: float = 0.8
    ki_duty_per_m: float = 3.0
    integral_limit_duty: float = 0.3
    integrate_band_mps: float = 0.08  # integrate only when the speed error is below this
    speed_filter_alpha: float = 0.3  # low-pass on the measured wheel speed (0..1 per tick)
    # Command profile: the received (v, w) is slewed at these body rates before it becomes
    # wheel targets. Their sum at a wheel (a + alpha Lw / 2 = 1.37 m/s^2) stays inside
    # max_accel_mps2, so neither wheel saturates and a turn starts and stops with the same
    # lag (without it the wheel that changes most saturates longer at the end of a turn
    # than at its start and the robot over-rotates, ~6 deg per quarter turn).
    cmd_accel_mps2: float = 0.8
    cmd_alpha_radps2: float = 3.0
    # A stop command (v = w = 0) brakes instead: both wheel targets fall to zero together
    # (the path's curvature is kept) at this rate, near the traction limit. This is the
    # emergency deceleration every safety stop relies on (deadman, e-stop, command timeout).
    stop_decel_mps2: float = 1.5
    watchdog_s: float = WATCHDOG_S
    watchdog_ramp_mps2: float = 2.0  # how fast the targets ramp to zero after a trip
    max_cmd_v_mps: float = 1.0  # the firmware's own clamp on a received command
    max_cmd_w_radps: float = 3.0
    # Dead wheels.
    counts_per_rev: int = DW_COUNTS_PER_REV
    dead_wheel_diameter_m: float = DW_WHEEL_DIAMETER_M
    straight_offset_y_m: float = DW_S_OFFSET_Y_M
    horizontal_offset_x_m: float = DW_H_OFFSET_X_M
    velocity_window_ticks: int = 5  # ODOM v, w: mean over the last ticks (quantisation)
    # Battery.
    capacity_ah: float = 20.0
    initial_charge: float = 0.9  # 0..1
    internal_resistance_ohm: float = 0.08
    idle_current_a: float = 1.5  # electronics
    motor_current_a: float = 8.0  # both motors at full duty
    ocv_curve: tuple[tuple[float, float], ...] = DEFAULT_OCV_CURVE
    # The true divider ratio. The firmware's 5.545 x 0.9848 calibration is exact for it.
    divider_ratio: float = ADC_FACTOR * ADC_CALIBRATION
    adc_noise_counts: float = 1.0
    # IMU (BNO08x).
    gyro_bias_std_radps: float = 0.01  # per-axis bias, drawn once at power-up
    gyro_noise_std_radps: float = 0.002
    accel_noise_std_mps2: float = 0.02

    @property
    def metres_per_count(self) -> float:
        return math.pi * self.dead_wheel_diameter_m / self.counts_per_rev


@dataclass(frozen=True)
class EncoderFaults:
    """Mechanical faults of the dead wheels (the seed's "steers toward walls" issue).

    A tilted wheel rolls along a direction turned by the tilt: the straight wheel then
    reads ``v_s cos(a)``, the horizontal one ``w x_h cos(b) + v sin(b)``, so on a
    straight run the firmware sees a phantom turn rate ``v sin(b) / x_h`` that its PI
    loop "corrects" by really turning the other way (docs/mcu.md).
    """

    straight_tilt_rad: float = 0.0
    horizontal_tilt_rad: float = 0.0
    straight_slip: float = 0.0  # mean fraction of travel lost (0..1), random per tick
    horizontal_slip: float = 0.0
    noise_m: float = 0.0  # std of travel noise per control tick (m)
