"""Models of the robot's STM32 firmware, one per dialect (``mcu.firmware``):

- ``documented`` (:class:`FirmwareModel`, seed section 6): RX state machine, command
  watchdog, PI motor control with ESC PWM, dead-wheel odometry with faults, battery ADC
  and IMU;
- ``seed-2025`` (:class:`Seed2025Model`): what the seed robot runs today: 9-byte 0x78
  command blocks, no watchdog, motor-encoder odometry, coarse ESC steps, no battery.

Pure (numpy + stdlib, seeded Generator); sim/mcu_pty.py puts either behind a pty.
"""

from sage_robot.sim.firmware.dialects import FIRMWARE_DIALECTS, SimFirmware, make_firmware
from sage_robot.sim.firmware.model import FirmwareModel
from sage_robot.sim.firmware.params import EncoderFaults, FirmwareParams
from sage_robot.sim.firmware.seed2025 import Seed2025Model
from sage_robot.sim.firmware.seed2025_params import Seed2025Params

__all__ = [
    "FIRMWARE_DIALECTS",
    "EncoderFaults",
    "FirmwareModel",
    "FirmwareParams",
    "Seed2025Model",
    "Seed2025Params",
    "SimFirmware",
    "make_firmware",
]
