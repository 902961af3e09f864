"""ROS map_server maps: read and write YAML + image (PGM, PNG), and cell ↔ world transforms.

Conventions (as map_server / Nav2 ``map_io``):

- The image's top row is the map's far (+y) edge; :class:`OccupancyGrid` stores
  ``data[row, col]`` with row 0 at the *origin* (bottom), so rows are flipped on read.
- ``origin: [x, y, yaw]`` is the pose of the lower-left pixel's corner in the map frame.
- With ``negate: 0`` a pixel v has occupancy p = (255 - v) / 255 (``negate: 1``: v / 255).
  ``trinary``: p > occupied_thresh → 100, p < free_thresh → 0, else -1 (unknown).
  ``scale``: as trinary at the ends, in between 99·(p - free)/(occ - free); a transparent
  pixel is unknown. ``raw``: the pixel value itself (0..100), anything else unknown.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from PIL import Image, UnidentifiedImageError

from sage_robot.core.errors import ConfigError
from sage_robot.core.msgs import OccupancyGrid, Pose2D

FREE, OCCUPIED, UNKNOWN = 0, 100, -1
# What map_saver writes for each class in trinary mode.
PIXEL_FREE, PIXEL_OCCUPIED, PIXEL_UNKNOWN = 254, 0, 205
DEFAULT_OCCUPIED_THRESH = 0.65
DEFAULT_FREE_THRESH = 0.25  # the seed's robot edits this to 0.1 after SLAM
MODES = ("trinary", "scale", "raw")
SAVER_FREE_MAX = 25  # map_saver's default free threshold, on the 0..100 cell scale
SAVER_OCCUPIED_MIN = 65  # map_saver's default occupied threshold, on the 0..100 cell scale


@dataclass(frozen=True)
class MapMeta:
    """The YAML half of a map."""

    image: Path
    resolution: float
    origin: tuple[float, float, float]
    negate: bool = False
    occupied_thresh: float = DEFAULT_OCCUPIED_THRESH
    free_thresh: float = DEFAULT_FREE_THRESH
    mode: str = "trinary"


def _meta_from_yaml(path: Path) -> MapMeta:
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"{path}: map file not found") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML: {exc}") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a map_server YAML mapping")

    def need(key: str) -> Any:
        if key not in data:
            raise ConfigError(f"{path}: missing key '{key}'")
        return data[key]

    try:
        origin = tuple(float(v) for v in need("origin"))
        if len(origin) != 3:
            raise ValueError
    except (TypeError, ValueError):
        raise ConfigError(f"{path}: origin: expected [x, y, yaw], got {data.get('origin')!r}") from None
    try:
        resolution = float(need("resolution"))
        occ = float(data.get("occupied_thresh", DEFAULT_OCCUPIED_THRESH))
        free = float(data.get("free_thresh", DEFAULT_FREE_THRESH))
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{path}: resolution and thresholds must be numbers ({exc})") from None
    if resolution <= 0:
        raise ConfigError(f"{path}: resolution must be > 0 m per cell, got {resolution}")
    if not 0 <= free < occ <= 1:
        raise ConfigError(f"{path}: need 0 <= free_thresh < occupied_thresh <= 1, got {free} and {occ}")
    mode = str(data.get("mode", "trinary"))
    if mode not in MODES:
        raise ConfigError(f"{path}: mode must be one of {', '.join(MODES)}, got {mode!r}")
    image = Path(str(need("image")))
    if not image.is_absolute():
        image = path.parent / image
    return MapMeta(image, resolution, origin, bool(int(data.get("negate", 0))), occ, free, mode)  # type: ignore[arg-type]


def _classify(pixels: np.ndarray, alpha: np.ndarray | None, meta: MapMeta) -> np.ndarray:
    if meta.mode == "raw":
        out = np.where(pixels <= OCCUPIED, pixels, UNKNOWN).astype(np.int8)
    else:
        p = pixels.astype(np.float64) / 255.0
        if not meta.negate:
            p = 1.0 - p
        out = np.full(pixels.shape, UNKNOWN, dtype=np.int8)
        out[p > meta.occupied_thresh] = OCCUPIED
        out[p < meta.free_thresh] = FREE
        if meta.mode == "scale":
            mid = (p >= meta.free_thresh) & (p <= meta.occupied_thresh)
            scaled = 99.0 * (p - meta.free_thresh) / (meta.occupied_thresh - meta.free_thresh)
            out[mid] = np.rint(scaled[mid]).astype(np.int8)
    if alpha is not None and meta.mode == "scale":
        out[alpha == 0] = UNKNOWN
    return out


def read_map(yaml_path: str | Path) -> OccupancyGrid:
    """Read a map_server map. Errors name the file and the problem."""
    path = Path(yaml_path)
    meta = _meta_from_yaml(path)
    try:
        with Image.open(meta.image) as img:
            alpha = np.asarray(img.getchannel("A")) if img.mode in ("RGBA", "LA") else None
            gray = img.convert("L") if img.mode not in ("L", "I", "I;16") else img
            pixels = np.asarray(gray)
    except FileNotFoundError:
        raise ConfigError(f"{path}: image {meta.image} not found") from None
    except (UnidentifiedImageError, OSError) as exc:
        raise ConfigError(f"{path}: cannot read image {meta.image}: {exc}") from None
    if pixels.dtype != np.uint8:
        pixels = np.clip(pixels, 0, 255).astype(np.uint8)
    data = _classify(pixels, alpha, meta)[::-1].copy()  # image top row = far edge
    x, y, yaw = meta.origin
    return OccupancyGrid(0.0, "map", meta.resolution, Pose2D(x, y, yaw), data)


def write_map(
    grid: OccupancyGrid,
    yaml_path: str | Path,
    free_thresh: float = DEFAULT_FREE_THRESH,
    occupied_thresh: float = DEFAULT_OCCUPIED_THRESH,
    mode: str = "trinary",
) -> Path:
    """Write ``NAME.yaml`` + ``NAME.pgm`` as map_saver does. Trinary grids round-trip exactly;
    ``raw`` keeps every value 0..100."""
    path = Path(yaml_path)
    if mode not in ("trinary", "raw"):
        raise ValueError("write_map writes 'trinary' or 'raw' maps")
    data = grid.data
    if mode == "trinary":
        # As map_saver: a cell of value <= SAVER_FREE_MAX is free, >= SAVER_OCCUPIED_MIN occupied.
        pixels = np.full(data.shape, PIXEL_UNKNOWN, dtype=np.uint8)
        pixels[(data >= 0) & (data <= SAVER_FREE_MAX)] = PIXEL_FREE
        pixels[data >= SAVER_OCCUPIED_MIN] = PIXEL_OCCUPIED
    else:
        pixels = np.where(data < 0, 255, data).astype(np.uint8)
    image = path.with_suffix(".pgm")
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(pixels[::-1]).save(image)
    o = grid.origin
    meta = {
        "image": image.name,
        "mode": mode,
        "resolution": float(grid.resolution),
        "origin": [float(o.x), float(o.y), float(o.theta)],
        "negate": 0,
        "occupied_thresh": float(occupied_thresh),
        "free_thresh": float(free_thresh),
    }
    path.write_text(yaml.safe_dump(meta, sort_keys=False), encoding="utf-8")
    return path


# ---------------------------------------------------------------- transforms


def world_to_cell(
    grid: OccupancyGrid, x: np.ndarray | float, y: np.ndarray | float
) -> tuple[np.ndarray, np.ndarray]:
    """Map-frame points (m) → (row, col) integer indices (may be outside the grid)."""
    o = grid.origin
    dx, dy = np.asarray(x, dtype=np.float64) - o.x, np.asarray(y, dtype=np.float64) - o.y
    c, s = math.cos(o.theta), math.sin(o.theta)
    gx, gy = c * dx + s * dy, -s * dx + c * dy
    return (np.floor(gy / grid.resolution).astype(np.int64), np.floor(gx / grid.resolution).astype(np.int64))


def cell_to_world(
    grid: OccupancyGrid, row: np.ndarray | float, col: np.ndarray | float
) -> tuple[np.ndarray, np.ndarray]:
    """(row, col) → the map-frame coordinates (m) of the cell centre."""
    o = grid.origin
    gx = (np.asarray(col, dtype=np.float64) + 0.5) * grid.resolution
    gy = (np.asarray(row, dtype=np.float64) + 0.5) * grid.resolution
    c, s = math.cos(o.theta), math.sin(o.theta)
    return (o.x + c * gx - s * gy, o.y + s * gx + c * gy)


def in_bounds(grid: OccupancyGrid, row: np.ndarray, col: np.ndarray) -> np.ndarray:
    return (row >= 0) & (row < grid.height) & (col >= 0) & (col < grid.width)
