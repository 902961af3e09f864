"""Real sensors other than the MCU: lidar and camera."""

from __future__ import annotations

from pydantic import Field

from sage_robot.core.config.base import Section


class LidarSettings(Section):
    port: str = Field("/dev/ttyUSB0", description="RPLIDAR serial device (CP2102 adapter).")
    baud: int = Field(115200, gt=0, description="Serial speed (baud); A1 = 115200.")
    reconnect_s: float = Field(2.0, gt=0, description="Delay between reopen attempts (s).")


class CameraSettings(Section):
    device: str = Field("/dev/video0", description="V4L2 device path or index.")
    width: int = Field(480, gt=0, description="Image width (px), the seed's stream.")
    height: int = Field(270, gt=0, description="Image height (px).")
    fps: float = Field(15.0, gt=0, description="Frames per second published.")
    jpeg_quality: int = Field(70, ge=10, le=100, description="JPEG quality (10..100).")
