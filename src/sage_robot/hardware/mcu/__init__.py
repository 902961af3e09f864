"""The link to the STM32 motor controller: protocol table, decoder, port finding and the
serial bridge node."""

from sage_robot.hardware.mcu.protocol import (
    BATTERY,
    CMD,
    FRAME_TYPES,
    IMU,
    ODOM,
    SOF,
    Decoder,
    ErrorKind,
    Frame,
    FrameType,
    encode,
)

__all__ = [
    "BATTERY",
    "CMD",
    "FRAME_TYPES",
    "IMU",
    "ODOM",
    "SOF",
    "Decoder",
    "ErrorKind",
    "Frame",
    "FrameType",
    "encode",
]
