"""ROS map_server maps: read and write YAML + image (PGM, PNG), and cell ↔ world transforms.

Conventions (as Nav2's ``nav2_map_server/src/map_io.cpp``):

- The image's top row is the map's far (+y) edge; :class:`OccupancyGrid` stores
  ``data[row, col]`` with row 0 at the *origin* (bottom), so rows are flipped on read.
- ``origin: [x, y, yaw]`` is the pose of the lower-left pixel's corner in the map frame.
- A pixel's shade s is the mean of its colour channels / 255 (a grey image: its value;
  16-bit images / 65535); in ``trinary`` mode an image with alpha averages the alpha in
  too, as map_server does. Occupancy p = 1 - s (``negate: 1``: p = s).
- ``trinary``: p > occupied_thresh → 100, p < free_thresh → 0, else -1 (unknown).
  ``scale``: a pixel that is not opaque is unknown; else as trinary at the ends and
  rint(100·(p - free)/(occ - free)) in between. ``raw``: round(255·s) when 0..100, else
  unknown (``negate`` does not apply).
- Unknown stays unknown: map_saver writes unknown as 205 (p = 50/255 ≈ 0.196) and free as
  254, so a map needs ``free_thresh`` at most 0.196 (map_saver's own YAML says 0.196;
  the seed's robot uses 0.1). With Nav2's default 0.25 a grey pixel loads as *free*.
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
# map_saver's free_thresh: the unknown grey (205, p = 0.196078) is not < 0.196, so it stays
# unknown. Written by write_map and assumed when a YAML leaves the key out. (The seed's
# robot edits it to 0.1 after SLAM; Nav2's saver writes 0.25, which loads grey as free.)
DEFAULT_FREE_THRESH = 0.196
MODES = ("trinary", "scale", "raw")
SIXTEEN_BIT_MODES = ("I", "I;16", "I;16B", "I;16L")  # Pillow's modes of a 16-bit grey PGM/PNG
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
    data = _load_mapping(path)
    origin = _origin(path, data)
    resolution, occ, free = _scale_and_thresholds(path, data)
    mode = str(data.get("mode", "trinary"))
    if mode not in MODES:
        raise ConfigError(f"{path}: mode must be one of {', '.join(MODES)}, got {mode!r}")
    image = Path(str(_need(path, data, "image")))
    if not image.is_absolute():
        image = path.parent / image
    return MapMeta(image, resolution, origin, bool(int(data.get("negate", 0))), occ, free, mode)


def _load_mapping(path: Path) -> dict[str, Any]:
    """The map YAML's top-level mapping."""
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"{path}: map file not found") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML: {exc}") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a map_server YAML mapping")
    return data


def _need(path: Path, data: dict[str, Any], key: str) -> Any:
    if key not in data:
        raise ConfigError(f"{path}: missing key '{key}'")
    return data[key]


def _origin(path: Path, data: dict[str, Any]) -> tuple[float, float, float]:
    try:
        x, y, yaw = (float(v) for v in _need(path, data, "origin"))
    except (TypeError, ValueError):
        raise ConfigError(f"{path}: origin: expected [x, y, yaw], got {data.get('origin')!r}") from None
    return x, y, yaw


def _scale_and_thresholds(path: Path, data: dict[str, Any]) -> tuple[float, float, float]:
    """(resolution, occupied_thresh, free_thresh), checked."""
    try:
        resolution = float(_need(path, data, "resolution"))
        occ = float(data.get("occupied_thresh", DEFAULT_OCCUPIED_THRESH))
        free = float(data.get("free_thresh", DEFAULT_FREE_THRESH))
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{path}: resolution and thresholds must be numbers ({exc})") from None
    if resolution <= 0:
        raise ConfigError(f"{path}: resolution must be > 0 m per cell, got {resolution}")
    if not 0 <= free < occ <= 1:
        raise ConfigError(f"{path}: need 0 <= free_thresh < occupied_thresh <= 1, got {free} and {occ}")
    return resolution, occ, free


def _classify(shade: np.ndarray, alpha: np.ndarray | None, meta: MapMeta) -> np.ndarray:
    """Cells from shades 0..1 (and alpha 0..1, 1 = opaque), exactly as map_io.cpp."""
    if meta.mode == "raw":
        value = np.rint(shade * 255.0)
        return np.where(value <= OCCUPIED, value, UNKNOWN).astype(np.int8)
    occ = shade if meta.negate else 1.0 - shade
    out = np.full(shade.shape, UNKNOWN, dtype=np.int8)
    out[meta.occupied_thresh < occ] = OCCUPIED
    out[occ < meta.free_thresh] = FREE
    if meta.mode == "scale":
        mid = (occ >= meta.free_thresh) & (occ <= meta.occupied_thresh)
        scaled = 100.0 * (occ - meta.free_thresh) / (meta.occupied_thresh - meta.free_thresh)
        out[mid] = np.rint(scaled[mid]).astype(np.int8)
        if alpha is not None:
            out[alpha < 1.0] = UNKNOWN
    return out


def _shades(img: Image.Image, mode: str) -> tuple[np.ndarray, np.ndarray | None]:
    """(shade, alpha), both 0..1: the mean of the colour channels, and in ``trinary`` mode
    the alpha averaged in as one more channel (map_io.cpp keeps that old behaviour).
    Computed as map_io.cpp does, (sum / channels) / max, so ties at a threshold agree."""
    if img.mode in SIXTEEN_BIT_MODES:
        return np.asarray(img, dtype=np.float64) / 65535.0, None
    if img.mode in ("L", "LA", "RGB", "RGBA"):
        rgba = img
    else:  # palette, bilevel, CMYK...: as the colours they stand for
        transparent = "A" in img.getbands() or "transparency" in img.info
        rgba = img.convert("RGBA" if transparent else "RGB")
    arr = np.asarray(rgba, dtype=np.float64)
    if arr.ndim == 2:  # L
        return arr / 255.0, None
    has_alpha = rgba.mode in ("LA", "RGBA")
    colour = arr[..., :-1] if has_alpha else arr
    colour_sum = colour.sum(axis=-1) * (3 if colour.shape[-1] == 1 else 1)  # LA: grey counts as R, G, B
    alpha = arr[..., -1] if has_alpha else None
    if alpha is not None and mode == "trinary":
        return (colour_sum + alpha) / 4.0 / 255.0, alpha / 255.0
    return colour_sum / 3.0 / 255.0, None if alpha is None else alpha / 255.0


def read_map(yaml_path: str | Path) -> OccupancyGrid:
    """Read a map_server map. Errors name the file and the problem."""
    path = Path(yaml_path)
    meta = _meta_from_yaml(path)
    try:
        with Image.open(meta.image) as img:
            shade, alpha = _shades(img, meta.mode)
    except FileNotFoundError:
        raise ConfigError(f"{path}: image {meta.image} not found") from None
    except (UnidentifiedImageError, OSError) as exc:
        raise ConfigError(f"{path}: cannot read image {meta.image}: {exc}") from None
    data = _classify(shade, alpha, meta)[::-1].copy()  # image top row = far edge
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
