"""The robot's simulated camera: a first-person 480×270 view rendered by ray casting.

One ray per image column against the map (walls of ``WALL_HEIGHT_M``), the people
(cylinders: legs, shirt, head) and the low obstacles (boxes of their height), then a
per-pixel depth test. The floor carries a 1 m checker and the walls a stripe every metre,
so an operator sees motion and distance. Good enough to steer by, nothing more.

Image convention: row 0 at the top, column 0 on the left; RGB uint8. The camera looks
along the robot's heading from ``MOUNT_FORWARD_M`` ahead of its centre at ``HEIGHT_M``.
"""

from __future__ import annotations

import io
import math
from dataclasses import dataclass

import numpy as np
from PIL import Image

from sage_robot.sim.raycast import GridRaycaster, ray_boxes

WIDTH, HEIGHT = 480, 270  # as the seed's camera stream
HFOV_RAD = math.radians(70.0)
HEIGHT_M = 1.0  # lens height above the floor
MOUNT_FORWARD_M = 0.2
WALL_HEIGHT_M = 2.6
MAX_RANGE_M = 30.0
PERSON_HEIGHT_M = 1.7
HEAD_FROM_M = 1.45
SHIRT_FROM_M = 0.85
TILE_M = 1.0  # floor checker
STRIPE_M = 1.0  # wall stripe spacing
STRIPE_WIDTH = 0.04  # fraction of STRIPE_M
FOG_M = 12.0  # brightness halves about every FOG_M
JPEG_QUALITY = 80
NO_DEPTH = 1e6  # m: "nothing in this column" (finite, so products stay defined)
RENDER_SCALE = 2  # render at 1/2 resolution and scale up: 4x cheaper, fine to steer by
FPS = 15.0

CEILING_RGB = np.array([205, 205, 215], dtype=np.float32)
FLOOR_RGB = (np.array([150, 140, 120], dtype=np.float32), np.array([120, 112, 96], dtype=np.float32))
WALL_RGB = np.array([222, 214, 190], dtype=np.float32)
STRIPE_RGB = np.array([120, 110, 95], dtype=np.float32)
SKIN_RGB = np.array([224, 172, 135], dtype=np.float32)
TROUSERS_RGB = np.array([40, 50, 80], dtype=np.float32)
SHIRTS_RGB = np.array(
    [[200, 40, 40], [40, 140, 60], [40, 90, 200], [220, 160, 30], [140, 60, 160], [30, 160, 170]],
    dtype=np.float32,
)
BOX_RGB = {
    "bench": np.array([130, 85, 45], dtype=np.float32),
    "cart": np.array([110, 115, 125], dtype=np.float32),
}


@dataclass(frozen=True)
class Scene:
    """What the camera can see besides the map (map frame, m, rad)."""

    people: np.ndarray  # (n, 4): x, y, radius, id
    boxes: np.ndarray  # (k, 6): x, y, length, depth, yaw, height
    box_kinds: tuple[str, ...] = ()


class Camera:
    def __init__(
        self, raycaster: GridRaycaster, width: int = WIDTH, height: int = HEIGHT, scale: int = RENDER_SCALE
    ) -> None:
        self.raycaster, self.out_w, self.out_h = raycaster, width, height
        self.w, self.h = width // scale, height // scale
        width, height = self.w, self.h
        self.f = (width / 2) / math.tan(HFOV_RAD / 2)  # focal length (px)
        u = np.arange(width) + 0.5
        self.offsets = np.arctan((width / 2 - u) / self.f)  # column angle, + = left
        self.cos_off = np.cos(self.offsets)
        rows = np.arange(height, dtype=np.float64)[:, None] + 0.5
        self.rows = rows
        below = np.maximum(rows - height / 2, 1e-3)
        self.floor_depth = self.f * HEIGHT_M / below  # (h, 1) perpendicular distance of floor rows

    def render(self, robot: tuple[float, float, float], scene: Scene) -> np.ndarray:
        """An (h, w, 3) uint8 RGB image of the view from ``robot`` (x, y, theta)."""
        x, y, th = robot
        cx, cy = x + MOUNT_FORWARD_M * math.cos(th), y + MOUNT_FORWARD_M * math.sin(th)
        angles = th + self.offsets
        dirs = np.stack([np.cos(angles), np.sin(angles)])
        img = self._background(cx, cy, dirs)
        zbuf = np.full((self.h, self.w), np.inf, dtype=np.float32)
        t = self.raycaster.cast(cx, cy, angles, MAX_RANGE_M)
        self._walls(img, zbuf, cx, cy, dirs, t)
        if scene.boxes.size:
            self._boxes(img, zbuf, cx, cy, angles, scene)
        if scene.people.size:
            self._people(img, zbuf, cx, cy, angles, scene.people)
        small = Image.fromarray(np.clip(img, 0, 255).astype(np.uint8), "RGB")
        if small.size != (self.out_w, self.out_h):
            small = small.resize((self.out_w, self.out_h), Image.Resampling.BILINEAR)
        return np.asarray(small)

    def jpeg(self, robot: tuple[float, float, float], scene: Scene) -> bytes:
        return encode_jpeg(self.render(robot, scene))

    # ---------------------------------------------------------------- layers
    def _background(self, cx: float, cy: float, dirs: np.ndarray) -> np.ndarray:
        img = np.empty((self.h, self.w, 3), dtype=np.float32)
        half = self.h // 2
        dist = self.floor_depth[half:] / self.cos_off[None, :]  # along-ray floor distance
        fx, fy = cx + dist * dirs[0][None, :], cy + dist * dirs[1][None, :]
        checker = ((np.floor(fx / TILE_M) + np.floor(fy / TILE_M)) % 2).astype(bool)
        fog = _fog(dist)[..., None]
        img[half:] = np.where(checker[..., None], FLOOR_RGB[0], FLOOR_RGB[1]) * fog
        above = np.maximum(self.h / 2 - self.rows[:half], 1e-3)
        ceil_fog = _fog(self.f * (WALL_HEIGHT_M - HEIGHT_M) / above)  # (half, 1)
        img[:half] = CEILING_RGB * ceil_fog[:, :, None]
        return img

    def _walls(
        self, img: np.ndarray, zbuf: np.ndarray, cx: float, cy: float, dirs: np.ndarray, t: np.ndarray
    ) -> None:
        hit = np.isfinite(t)
        if not hit.any():
            return
        depth = np.where(hit, t * self.cos_off, np.inf)
        top = self.h / 2 - self.f * (WALL_HEIGHT_M - HEIGHT_M) / depth
        bottom = self.h / 2 + self.f * HEIGHT_M / depth
        mask = hit[None, :] & (self.rows >= top[None, :]) & (self.rows < bottom[None, :])
        tf = np.where(hit, t, 0.0)
        hx, hy = cx + tf * dirs[0], cy + tf * dirs[1]
        res = self.raycaster.res
        gx, gy = self.raycaster.to_grid(0.0, 0.0)
        fx = np.abs((hx / res - gx) - np.round(hx / res - gx))
        fy = np.abs((hy / res - gy) - np.round(hy / res - gy))
        x_face = fx < fy  # the ray crossed a vertical cell boundary: a wall facing east/west
        along = np.where(x_face, hy, hx)
        stripe = (along / STRIPE_M) % 1.0 < STRIPE_WIDTH
        shade = np.where(x_face, 0.82, 1.0) * _fog(tf)
        colour = np.where(stripe[:, None], STRIPE_RGB, WALL_RGB) * shade[:, None]
        img[mask] = np.broadcast_to(colour[None, :, :], img.shape)[mask]
        zbuf[mask] = np.broadcast_to(depth[None, :], zbuf.shape)[mask]

    def _z_of_rows(self, depth: np.ndarray) -> np.ndarray:
        """Height (m) above the floor seen at each pixel for objects at per-column ``depth``."""
        z: np.ndarray = HEIGHT_M + (self.h / 2 - self.rows) * depth[None, :] / self.f
        return z

    def _boxes(
        self, img: np.ndarray, zbuf: np.ndarray, cx: float, cy: float, angles: np.ndarray, scene: Scene
    ) -> None:
        t, idx = ray_boxes(cx, cy, angles, scene.boxes[:, :5])
        hit = idx >= 0
        if not hit.any():
            return
        depth = np.where(hit, t * self.cos_off, NO_DEPTH).astype(np.float32)
        height = np.where(hit, scene.boxes[np.maximum(idx, 0), 5], 0.0)
        z = self._z_of_rows(depth)
        mask = hit[None, :] & (z >= 0.0) & (z <= height[None, :]) & (depth[None, :] < zbuf)
        kinds = [scene.box_kinds[i] if i < len(scene.box_kinds) else "bench" for i in range(len(scene.boxes))]
        palette = np.stack([BOX_RGB.get(k, BOX_RGB["bench"]) for k in kinds])
        colour = palette[np.maximum(idx, 0)] * _fog(np.where(hit, t, 0.0))[:, None]
        top = z > height[None, :] - 0.05  # a lighter top edge
        col_img = np.broadcast_to(colour[None, :, :], img.shape) * np.where(top, 1.25, 1.0)[..., None]
        img[mask] = col_img[mask]
        zbuf[mask] = np.broadcast_to(depth[None, :], zbuf.shape)[mask]

    def _people(
        self, img: np.ndarray, zbuf: np.ndarray, cx: float, cy: float, angles: np.ndarray, people: np.ndarray
    ) -> None:
        dx, dy = np.cos(angles)[:, None], np.sin(angles)[:, None]
        fx, fy = people[None, :, 0] - cx, people[None, :, 1] - cy
        b = fx * dx + fy * dy
        disc = b * b - (fx * fx + fy * fy - people[None, :, 2] ** 2)
        with np.errstate(invalid="ignore"):
            tt = np.where((disc >= 0) & (b > 0), b - np.sqrt(np.maximum(disc, 0.0)), np.inf)
        which = np.argmin(tt, axis=1)
        t = tt[np.arange(len(angles)), which]
        hit = np.isfinite(t) & (t > 0.05)
        if not hit.any():
            return
        depth = np.where(hit, t * self.cos_off, NO_DEPTH).astype(np.float32)
        z = self._z_of_rows(depth)
        mask = hit[None, :] & (z >= 0.0) & (z <= PERSON_HEIGHT_M) & (depth[None, :] < zbuf)
        shirt = SHIRTS_RGB[people[which, 3].astype(np.int64) % len(SHIRTS_RGB)]
        fog = _fog(np.where(hit, t, 0.0))[None, :, None]
        layer = (
            np.where(
                (z >= HEAD_FROM_M)[..., None],
                SKIN_RGB,
                np.where((z >= SHIRT_FROM_M)[..., None], shirt[None, :, :], TROUSERS_RGB),
            )
            * fog
        )
        img[mask] = layer[mask]
        zbuf[mask] = np.broadcast_to(depth[None, :], zbuf.shape)[mask]


def _fog(dist: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.asarray(dist, dtype=np.float32) / FOG_M)


def encode_jpeg(rgb: np.ndarray, quality: int = JPEG_QUALITY) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(rgb, "RGB").save(buf, "JPEG", quality=quality)
    return buf.getvalue()
