"""A model of the robot's STM32 firmware (seed section 6): RX state machine, command
watchdog, PI motor control with ESC PWM, dead-wheel odometry with faults, battery ADC and
IMU. Pure (numpy + stdlib, seeded Generator); sim/mcu_pty.py puts it behind a pty."""

from sage_robot.sim.firmware.model import FirmwareModel
from sage_robot.sim.firmware.params import EncoderFaults, FirmwareParams

__all__ = ["EncoderFaults", "FirmwareModel", "FirmwareParams"]
