"""Camera node: a clear 'absent' on a machine without one; JPEG frames from a frame source."""

import asyncio
import io

import numpy as np
from PIL import Image

from sage_robot.core.bus import Bus
from sage_robot.core.clock import WallClock
from sage_robot.core.config import load_profile
from sage_robot.core.msgs import CompressedImage
from sage_robot.core.node import NodeContext
from sage_robot.hardware.camera import CameraNode

from ..support.waits import WAIT_S, until


async def test_absent_camera_is_reported_clearly(tmp_path):
    settings = load_profile(None, {"camera": {"device": str(tmp_path / "video9")}})
    bus = Bus(WallClock())
    node = CameraNode(NodeContext(bus, bus.clock, settings))
    await node.setup()
    # the first attempt runs in the background
    await until(lambda: node.stats()["last_error"], "the camera's first attempt to fail", WAIT_S)
    stats = node.stats()
    assert not stats["connected"]
    assert "not found" in stats["last_error"]
    assert "camera.device" in stats["last_error"]
    await node.teardown()


class Pattern:
    """A 640x480 test pattern standing in for the V4L2 device (same FrameSource interface)."""

    def __init__(self, cfg) -> None:
        self.n = 0

    def read(self) -> np.ndarray:
        self.n += 1
        frame = np.zeros((480, 640, 3), np.uint8)
        frame[:, : 64 * (self.n % 10)] = (0, 128, 255)
        return frame

    def close(self) -> None:
        pass


async def test_frames_are_scaled_to_the_seed_stream_and_jpeg():
    settings = load_profile(None, {"camera": {"fps": 50}})
    bus = Bus(WallClock())
    sub = bus.subscribe("/image_raw/compressed", CompressedImage)
    node = CameraNode(NodeContext(bus, bus.clock, settings), source_factory=Pattern)
    await node.setup()
    msg = await asyncio.wait_for(sub.get(), 5)
    await node.teardown()
    img = Image.open(io.BytesIO(msg.data))
    assert img.format == "JPEG"
    assert img.size == (480, 270)
