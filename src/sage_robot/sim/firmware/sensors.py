"""Battery (pack + ADC on PA4) and IMU (BNO08x) models of the firmware.

Battery: open-circuit voltage from the state of charge (4S Li-ion curve), minus the
internal-resistance drop of the current the motors draw (``motor_current_a`` at full
duty on both) plus the electronics' idle current; the charge falls by the current over
the capacity. The firmware sees it through a 100 ohm + 22 ohm divider and a 12-bit ADC
(3.3 V / 4095 counts) and reports ``counts * 3.3 / 4095 * 5.545 * 0.9848`` volts.

IMU: body-frame gyro (rad/s) and accelerometer (m/s^2, gravity on +z), each gyro axis
with a constant bias drawn at power-up plus white noise.
"""

from __future__ import annotations

import numpy as np

from sage_robot.sim.firmware.params import (
    ADC_CALIBRATION,
    ADC_FACTOR,
    ADC_MAX_COUNTS,
    ADC_VREF_V,
    GRAVITY_MPS2,
    FirmwareParams,
)

SECONDS_PER_HOUR = 3600.0


class Battery:
    def __init__(self, params: FirmwareParams, rng: np.random.Generator) -> None:
        self.p, self.rng = params, rng
        self.charge = params.initial_charge  # 0..1
        self.current_a = params.idle_current_a
        soc, volts = zip(*params.ocv_curve, strict=True)
        self._soc, self._volts = np.array(soc), np.array(volts)

    @property
    def open_circuit_v(self) -> float:
        return float(np.interp(self.charge, self._soc, self._volts))

    @property
    def voltage(self) -> float:
        """Terminal voltage under the present load (V)."""
        return self.open_circuit_v - self.current_a * self.p.internal_resistance_ohm

    def step(self, dt: float, effort: float) -> None:
        """``effort``: mean |duty| of the two motors (0..1)."""
        p = self.p
        self.current_a = p.idle_current_a + p.motor_current_a * min(1.0, abs(effort))
        used = self.current_a * dt / (p.capacity_ah * SECONDS_PER_HOUR)
        self.charge = max(0.0, self.charge - used)

    def adc_counts(self) -> int:
        """What ADC1 reads on PA4 (0..4095)."""
        pin_v = self.voltage / self.p.divider_ratio
        raw = pin_v / ADC_VREF_V * ADC_MAX_COUNTS + self.rng.normal(0.0, self.p.adc_noise_counts)
        return int(np.clip(round(raw), 0, ADC_MAX_COUNTS))

    def measured_voltage(self) -> float:
        """The firmware's conversion of one ADC reading (V), as sent in BATTERY frames."""
        return self.adc_counts() * ADC_VREF_V / ADC_MAX_COUNTS * ADC_FACTOR * ADC_CALIBRATION


class ImuModel:
    def __init__(self, params: FirmwareParams, rng: np.random.Generator) -> None:
        self.p, self.rng = params, rng
        self.gyro_bias = rng.normal(0.0, params.gyro_bias_std_radps, 3)
        self.accel = np.array([0.0, 0.0, GRAVITY_MPS2])
        self.gyro = np.zeros(3)
        self._v_prev = 0.0

    def step(self, dt: float, v: float, w: float) -> None:
        """Truth for this step: forward speed v (m/s) and turn rate w (rad/s)."""
        a_fwd = (v - self._v_prev) / dt if dt > 0 else 0.0
        self._v_prev = v
        self.gyro = np.array([0.0, 0.0, w])
        self.accel = np.array([a_fwd, v * w, GRAVITY_MPS2])

    def sample(self) -> tuple[float, ...]:
        """(gx, gy, gz, ax, ay, az) as the sensor reports them."""
        p = self.p
        gyro = self.gyro + self.gyro_bias + self.rng.normal(0.0, p.gyro_noise_std_radps, 3)
        accel = self.accel + self.rng.normal(0.0, p.accel_noise_std_mps2, 3)
        return tuple(float(x) for x in np.concatenate([gyro, accel]))
