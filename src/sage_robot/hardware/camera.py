"""USB camera (V4L2 via OpenCV) → JPEG frames on ``/image_raw/compressed``.

The seed streamed 480×270 from a USB camera through web_video_server. Here the node grabs
frames in a thread, scales them to the profile's size and publishes JPEG. With no camera
it says so once, publishes nothing and keeps looking (plugging one in later works).
"""

from __future__ import annotations

import asyncio
import os
import threading
from typing import Any, Protocol

import numpy as np

from sage_robot.core import topics
from sage_robot.core.config.devices import CameraSettings
from sage_robot.core.errors import DeviceNotConnectedError
from sage_robot.core.msgs import CompressedImage
from sage_robot.core.node import Node

RETRY_S = 2.0


class FrameSource(Protocol):
    """Anything that gives BGR frames: the V4L2 camera, or a test pattern."""

    def read(self) -> np.ndarray: ...

    def close(self) -> None: ...


class V4l2Camera:
    def __init__(self, cfg: CameraSettings) -> None:
        try:
            import cv2
        except ImportError:
            raise DeviceNotConnectedError(
                "OpenCV is not installed, so no camera can be read: pip install 'sage-robot[robot]'"
            ) from None

        self._cv2 = cv2
        dev: int | str = int(cfg.device) if cfg.device.isdigit() else cfg.device
        if isinstance(dev, str) and not os.path.exists(dev):
            raise DeviceNotConnectedError(
                f"camera {dev} not found: plug in the USB camera (ls /dev/video*) or set camera.device"
            )
        self._cap = cv2.VideoCapture(dev, cv2.CAP_V4L2)
        if not self._cap.isOpened():
            raise DeviceNotConnectedError(f"camera {dev} exists but cannot be opened (in use? permissions?)")
        self._cap.set(cv2.CAP_PROP_FRAME_WIDTH, cfg.width)
        self._cap.set(cv2.CAP_PROP_FRAME_HEIGHT, cfg.height)

    def read(self) -> np.ndarray:
        ok, frame = self._cap.read()
        if not ok:
            raise DeviceNotConnectedError("camera stopped delivering frames")
        return frame

    def close(self) -> None:
        self._cap.release()


def encode_jpeg(frame: np.ndarray, width: int, height: int, quality: int) -> bytes:
    """Scale a BGR frame to (width, height) and JPEG-encode it."""
    import cv2

    if frame.shape[1] != width or frame.shape[0] != height:
        frame = cv2.resize(frame, (width, height), interpolation=cv2.INTER_AREA)
    ok, buf = cv2.imencode(".jpg", frame, [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise ValueError("JPEG encoding failed")
    return buf.tobytes()


class CameraNode(Node):
    name = "camera"

    def __init__(self, ctx: Any, source_factory: Any = None) -> None:
        super().__init__(ctx)
        self._factory = source_factory or V4l2Camera
        self.frames = 0
        self.connected = False
        self.last_error = ""

    async def setup(self) -> None:
        self._stop = threading.Event()
        self._thread = self.start_thread(self._grab, "camera")

    def _grab(self) -> None:
        cfg = self.settings.camera
        warned = False
        while not self._stop.is_set():
            try:
                source = self._factory(cfg)
            except DeviceNotConnectedError as exc:
                self.connected, self.last_error = False, str(exc)
                if not warned:
                    self.log.warning("no camera", error=str(exc))
                    warned = True
                self._stop.wait(RETRY_S)
                continue
            self.connected, warned = True, False
            try:
                while not self._stop.is_set():
                    jpeg = encode_jpeg(source.read(), cfg.width, cfg.height, cfg.jpeg_quality)
                    self.bus.publish_threadsafe(
                        topics.CAMERA, CompressedImage(self.clock.now(), "camera", "jpeg", jpeg)
                    )
                    self.frames += 1
                    self._stop.wait(1.0 / cfg.fps)
            except DeviceNotConnectedError as exc:
                self.connected, self.last_error = False, str(exc)
                self.log.warning("camera lost", error=str(exc))
            finally:
                source.close()

    async def teardown(self) -> None:
        self._stop.set()
        await asyncio.to_thread(self._thread.join, 3.0)

    def stats(self) -> dict[str, Any]:
        return {"connected": self.connected, "frames": self.frames, "last_error": self.last_error}
