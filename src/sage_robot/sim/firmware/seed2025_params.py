"""Constants of the seed-2025 STM32 firmware (what the seed robot runs today) and of the
motors, encoders and ESCs it drives. Units are SI unless the name says otherwise.

Encoders: 100 counts per motor revolution, both edges of one channel counted (x2), so 200
counts per motor revolution; the gear ratio 1.25 is read as *motor revolutions per wheel
revolution* (the encoder sits on the motor shaft, before the gearbox), so a wheel turn is
250 counts and one count is pi x 0.101 m / 250 = 1.269 mm of wheel travel.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from sage_robot.sim.firmware.params import FirmwareParams

SEED_TRACK_WIDTH_M = 0.483  # the firmware's wheel-to-wheel track constant
SEED_WHEEL_DIAMETER_M = 0.101  # drive wheel diameter
SEED_ENCODER_CPR = 100  # encoder counts per motor revolution, one edge
SEED_ENCODER_EDGES = 2  # x2 decoding: 200 counts per motor revolution
SEED_GEAR_RATIO = 1.25  # motor revolutions per wheel revolution
SEED_CTRL_HZ = 100.0  # PI loop and odometry rate (Hz)
SEED_KP = 0.2  # (m/s of PI output) per (m/s of wheel-speed error)
SEED_KI = 5.0  # 1/s: integral gain on the same error

# ESC mapping: pulse = 1500 + 70 u (u: PI output, m/s), then anything beyond 1400..1600
# jumps to a coarse step.
ESC_NEUTRAL_US = 1500.0
ESC_US_PER_MPS = 70.0  # us of pulse per m/s of PI output
ESC_LINEAR_LOW_US = 1400.0  # below: the pulse becomes ESC_STEP_LOW_US
ESC_LINEAR_HIGH_US = 1600.0  # above: the pulse becomes ESC_STEP_HIGH_US
ESC_STEP_LOW_US = 1250.0
ESC_STEP_HIGH_US = 1750.0
ESC_TICK_US = 1.0  # PWM timer resolution: the compare register counts whole us
ESC_NO_PULSE_US = 0.0  # a NaN pulse width lands in the compare register as 0: no pulse

SEED_BANNER = b"WHO_AM_I=0x71\r\n"  # printed on the UART at every boot
SEED_ODOM_PERIOD_S = 0.02  # ODOM at 50 Hz
SEED_IMU_PERIOD_S = 0.01  # IMU at 100 Hz


@dataclass(frozen=True)
class Seed2025Params:
    """Everything the seed-2025 model needs. Defaults are the seed robot's firmware."""

    track_width_m: float = SEED_TRACK_WIDTH_M  # the firmware's constant (not the profile's)
    wheel_diameter_m: float = SEED_WHEEL_DIAMETER_M
    encoder_cpr: int = SEED_ENCODER_CPR
    encoder_edges: int = SEED_ENCODER_EDGES
    gear_ratio: float = SEED_GEAR_RATIO  # motor revs per wheel rev
    control_hz: float = SEED_CTRL_HZ
    kp: float = SEED_KP  # dimensionless: m/s of output per m/s of error
    ki_per_s: float = SEED_KI
    # None: a plain PI, as the facts describe; it winds up while the ESC sits at a step
    # (a command beyond ~1 m/s), and then takes long to come back. A value (m/s) clamps it.
    integral_limit_mps: float | None = None
    # ESC + motor + chassis: a first-order lag toward the pulse's speed, 0.004 m/s per us
    # off neutral (1750 us = 1.0 m/s, 1600 us = 0.4 m/s), acceleration limited; coasting
    # (neutral or no pulse) adds friction.
    esc_mps_per_us: float = 1.0 / (ESC_STEP_HIGH_US - ESC_NEUTRAL_US)
    motor_tau_s: float = 0.15
    max_accel_mps2: float = 1.5
    friction_decel_mps2: float = 0.3
    # The physical pack (never reported: seed-2025 sends no BATTERY frame) and the IMU.
    initial_charge: float = 0.9  # 0..1
    gyro_bias_std_radps: float = 0.01
    gyro_noise_std_radps: float = 0.002
    accel_noise_std_mps2: float = 0.02

    @property
    def counts_per_wheel_rev(self) -> float:
        return self.encoder_cpr * self.encoder_edges * self.gear_ratio  # 250

    @property
    def metres_per_count(self) -> float:
        return math.pi * self.wheel_diameter_m / self.counts_per_wheel_rev

    @property
    def control_period_s(self) -> float:
        return 1.0 / self.control_hz

    def sensor_params(self) -> FirmwareParams:
        """The shared battery and IMU models' parameters (sim/firmware/sensors.py)."""
        return FirmwareParams(
            initial_charge=self.initial_charge,
            gyro_bias_std_radps=self.gyro_bias_std_radps,
            gyro_noise_std_radps=self.gyro_noise_std_radps,
            accel_noise_std_mps2=self.accel_noise_std_mps2,
        )
