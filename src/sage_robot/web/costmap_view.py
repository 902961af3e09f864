"""The navigator's costmap (``/nav/costmap``) as the teleop map's layer: a small RGBA PNG.

The ``costmap`` message on ``/ws/live`` carries the grid's geometry and the picture inline
(``png``: base64), as the map's: top row = highest y. Free and unknown cells are transparent;
the inflated band is a translucent blue that deepens with the cost; the inscribed band (the
robot's centre may not enter it) violet and lethal cells (walls, obstacles the lidar sees, people's
pads) magenta. A 160 × 160 grid is a few kilobytes, sent at most once a second.
"""

from __future__ import annotations

import base64
import io
from typing import Any

import numpy as np

from sage_robot.core.msgs import OccupancyGrid

BAND_RGB = (47, 129, 247)  # the inflated band (cost 1..98)
BAND_ALPHA_MIN, BAND_ALPHA_MAX = 40, 150  # its opacity (0..255) at the lowest and highest cost
INSCRIBED_RGBA = (163, 113, 247, 190)  # cost 99
LETHAL_RGBA = (255, 45, 150, 230)  # cost 100
INSCRIBED_VALUE, LETHAL_VALUE = 99, 100


def costmap_rgba(values: np.ndarray) -> np.ndarray:
    """Occupancy values (-1, 0..100), row 0 = lowest y → RGBA rows, top row = highest y."""
    v = np.asarray(values).astype(np.int16)
    out = np.zeros((*v.shape, 4), dtype=np.uint8)
    band = (v > 0) & (v < INSCRIBED_VALUE)
    out[band, :3] = BAND_RGB
    span = BAND_ALPHA_MAX - BAND_ALPHA_MIN
    out[band, 3] = (BAND_ALPHA_MIN + (v[band] - 1) * span // (INSCRIBED_VALUE - 2)).astype(np.uint8)
    out[v == INSCRIBED_VALUE] = INSCRIBED_RGBA
    out[v >= LETHAL_VALUE] = LETHAL_RGBA
    return np.ascontiguousarray(np.flipud(out))


def costmap_png(grid: OccupancyGrid) -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(costmap_rgba(grid.data), mode="RGBA").save(buf, format="PNG")
    return buf.getvalue()


def costmap_json(grid: OccupancyGrid) -> dict[str, Any]:
    """The ``costmap`` message of ``/ws/live``."""
    data = np.asarray(grid.data)
    return {
        "type": "costmap",
        "stamp": grid.stamp,
        "width": grid.width,
        "height": grid.height,
        "resolution": grid.resolution,
        "origin": {"x": grid.origin.x, "y": grid.origin.y, "theta": grid.origin.theta},
        "lethal": int(np.count_nonzero(data >= LETHAL_VALUE)),
        "png": base64.b64encode(costmap_png(grid)).decode("ascii"),
    }
