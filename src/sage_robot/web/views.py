"""Pure conversions from bus messages to what the pages draw (JSON-ready dicts, PNG bytes).

Frames: poses and points are in metres in the map frame (x right/east on the map image,
y up), angles in radians counter-clockwise. The pages turn them into pixels with the map's
``origin`` and ``resolution``.
"""

from __future__ import annotations

import io
import math
from typing import Any

import numpy as np

from sage_robot.core.geometry import compose, transform_points
from sage_robot.core.msgs import (
    BatteryState,
    LaserScan,
    OccupancyGrid,
    Path,
    Pose2D,
    PowerStatus,
)
from sage_robot.core.msgs.voice import UiState

MAX_SCAN_POINTS = 360  # lidar points sent to a page per scan (phones on Wi-Fi)
MAX_PATH_POINTS = 200  # plan points sent to a page
GRAY_UNKNOWN = 205  # map_server's colours: unknown grey, free white, occupied black
GRAY_FREE = 254


def battery_json(msg: BatteryState) -> dict[str, Any]:
    """``percentage`` in percent (0..100) as the seed's teleop page shows it, and ``pct``
    (0..1) and ``is_charging`` as the seed's face reads them; null when unknown."""
    known = not math.isnan(msg.percentage)
    return {
        "type": "battery",
        "voltage": round(msg.voltage, 2) if math.isfinite(msg.voltage) else None,
        "percentage": round(100.0 * msg.percentage, 1) if known else None,
        "pct": round(msg.percentage, 3) if known else None,
        "is_charging": msg.status is PowerStatus.CHARGING,
        "status": msg.status.value,
    }


SEED_PHASES = {"navigating": "searching"}  # SAGE's face phase -> the seed face's name for it


def seed_ui_state(state: dict[str, Any]) -> dict[str, Any]:
    """The same ``ui_state`` with the phase the seed's face page knows."""
    return dict(state, phase=SEED_PHASES.get(state["phase"], state["phase"]))


def ui_state_json(msg: UiState) -> dict[str, Any]:
    """The seed's face protocol: ``{type: "ui_state", phase, asr_partial, ...}``."""
    return {
        "type": "ui_state",
        "phase": msg.phase.value,
        "asr_partial": msg.asr_partial,
        "asr_final": msg.asr_final,
        "llm_tokens": msg.llm_tokens,
        "tts_viseme": round(float(msg.tts_viseme), 3),
        "error_msg": msg.error_msg,
    }


def pose_json(pose: Pose2D, frame: str) -> dict[str, Any]:
    return {
        "type": "pose",
        "frame": frame,
        "x": round(pose.x, 3),
        "y": round(pose.y, 3),
        "theta": round(pose.theta, 4),
    }


def scan_points(
    scan: LaserScan,
    robot: tuple[float, float, float],
    mount: tuple[float, float, float],
    max_points: int = MAX_SCAN_POINTS,
) -> np.ndarray:
    """Lidar returns as an (N, 2) array in the map frame.

    ``robot`` is base_link in the map frame, ``mount`` the lidar in base_link (x, y, yaw).
    Returns outside [range_min, range_max] or not finite are dropped; at most
    ``max_points`` evenly spaced points are kept.
    """
    r = np.asarray(scan.ranges, dtype=np.float64)
    a = scan.angles
    ok = np.isfinite(r) & (r >= scan.range_min) & (r <= scan.range_max)
    r, a = r[ok], a[ok]
    if len(r) > max_points:
        idx = np.linspace(0, len(r) - 1, max_points).astype(int)
        r, a = r[idx], a[idx]
    pts = np.column_stack((r * np.cos(a), r * np.sin(a)))
    return transform_points(compose(robot, mount), pts)


def scan_json(points: np.ndarray) -> dict[str, Any]:
    return {"type": "scan", "points": np.round(points, 2).tolist()}


def path_json(path: Path, kind: str = "plan", max_points: int = MAX_PATH_POINTS) -> dict[str, Any]:
    poses = path.poses
    if len(poses) > max_points:
        idx = np.linspace(0, len(poses) - 1, max_points).astype(int)
        poses = tuple(poses[i] for i in idx)
    return {"type": kind, "points": [[round(p.x, 2), round(p.y, 2)] for p in poses]}


def people_points(msg: Any) -> list[list[float]]:
    """People positions (m, map frame) from the simulator's message, whatever it is named.

    Looks for a sequence of items with ``x`` and ``y`` (directly or in a ``pose``/``position``).
    """
    from dataclasses import fields, is_dataclass

    def xy(item: Any) -> list[float] | None:
        for holder in (item, getattr(item, "pose", None), getattr(item, "position", None)):
            if holder is not None and hasattr(holder, "x") and hasattr(holder, "y"):
                return [round(float(holder.x), 2), round(float(holder.y), 2)]
        return None

    if not is_dataclass(msg):
        return []
    for f in fields(msg):
        value = getattr(msg, f.name)
        if isinstance(value, np.ndarray) and value.ndim == 2 and value.shape[1] >= 2:
            rows: list[list[float]] = np.round(value[:, :2].astype(float), 2).tolist()
            return rows
        if isinstance(value, (tuple, list)) and value:
            pts = [p for p in (xy(v) for v in value) if p is not None]
            if pts:
                return pts
    return []


def map_meta_json(grid: OccupancyGrid, version: int) -> dict[str, Any]:
    return {
        "type": "map",
        "version": version,
        "width": grid.width,
        "height": grid.height,
        "resolution": grid.resolution,
        "origin": {"x": grid.origin.x, "y": grid.origin.y, "theta": grid.origin.theta},
        "url": f"/api/map.png?v={version}",
    }


def map_png(grid: OccupancyGrid) -> bytes:
    """The grid as a grey PNG, top row = highest y (as map_server writes it)."""
    from PIL import Image

    data = np.asarray(grid.data)
    img = np.full(data.shape, GRAY_UNKNOWN, dtype=np.uint8)
    known = data >= 0
    occ = np.clip(data, 0, 100).astype(np.float32)
    img[known] = (GRAY_FREE - occ[known] * GRAY_FREE / 100.0).astype(np.uint8)
    buf = io.BytesIO()
    Image.fromarray(np.flipud(img), mode="L").save(buf, format="PNG", optimize=False)
    return buf.getvalue()
