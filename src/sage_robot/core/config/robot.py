"""The robot's body, its MCU link and its battery. Defaults describe the seed's robot."""

from __future__ import annotations

import itertools
from typing import Literal

from pydantic import Field, model_validator

from sage_robot.core.config.base import Section


class LidarMount(Section):
    x_m: float = Field(0.1466, description="Lidar forward of base_link (m).")
    y_m: float = Field(0.0, description="Lidar left of base_link (m).")
    z_m: float = Field(0.527, description="Scan-plane height above the floor (m).")
    yaw_rad: float = Field(0.0, description="Lidar yaw relative to base_link (rad).")


class RobotSettings(Section):
    name: str = Field("SAGE Jarvis", description="The robot's spoken name.")
    track_width_m: float = Field(0.381, gt=0, description="Wheel-to-wheel track width Lw (m).")
    radius_m: float = Field(0.25, gt=0, description="Footprint radius (m).")
    height_m: float = Field(1.2, gt=0, description="Body height (m).")
    max_linear_mps: float = Field(0.8, gt=0, description="Top forward speed (m/s).")
    max_angular_radps: float = Field(1.0, gt=0, description="Top turn rate (rad/s).")
    allow_reverse: bool = Field(False, description="Never drive backwards on tours (seed).")
    lidar: LidarMount = Field(default_factory=LidarMount)


class McuSettings(Section):
    firmware: Literal["seed-2025", "documented"] = Field(
        "seed-2025",
        description="The STM32 firmware's dialect: 'seed-2025' (what the seed robot runs today: "
        "9-byte 0x78 commands, no watchdog, no battery frames) or 'documented' (the seed "
        "document's framed protocol with a watchdog and BATTERY frames). docs/mcu.md.",
    )
    port: str = Field("auto", description="Serial device, or 'auto' to find /dev/ttyACM*.")
    baud: int = Field(115200, gt=0, description="Serial speed (baud).")
    resend_hz: float = Field(20.0, ge=10.0, description="Re-send rate of a standing command (Hz).")
    watchdog_s: float = Field(0.55, gt=0, description="MCU command watchdog (s).")
    imu_enabled: bool = Field(False, description="Publish /imu/data (the seed's IMU variant).")
    imu_calibration_s: float = Field(5.0, ge=0, description="Still time for gyro bias (s).")
    reconnect_s: float = Field(1.0, gt=0, description="Delay between reopen attempts (s).")
    cmd_timeout_s: float = Field(
        0.25,
        ge=0,
        description="A /cmd_vel older than this is replaced by a stop on the wire (s): the "
        "bridge's own dead-man, independent of the web deadman and the MCU's watchdog. "
        "Publishers of motion repeat their command (teleop every 0.1 s, the navigator at its "
        "controller rate); 0 = a command stands until the next one.",
    )


class BatterySettings(Section):
    discharge_curve: tuple[tuple[float, float], ...] = Field(
        ((12.0, 0.0), (13.2, 0.1), (14.0, 0.3), (14.8, 0.6), (15.6, 0.85), (16.8, 1.0)),
        description="(voltage V, charge 0..1) pairs, increasing: a 4S Li-ion pack.",
    )
    warn_fraction: float = Field(0.25, ge=0, le=1, description="Warn below this charge (0..1).")
    critical_fraction: float = Field(0.10, ge=0, le=1, description="Go home below this (0..1).")
    hysteresis_fraction: float = Field(0.03, ge=0, le=0.5, description="Re-arm margin (0..1).")

    @model_validator(mode="after")
    def _curve_increasing(self) -> BatterySettings:
        volts = [v for v, _ in self.discharge_curve]
        if len(volts) < 2 or any(b <= a for a, b in itertools.pairwise(volts)):
            raise ValueError("discharge_curve needs two or more points with increasing voltage")
        if self.critical_fraction >= self.warn_fraction:
            raise ValueError("critical_fraction must be below warn_fraction")
        return self
