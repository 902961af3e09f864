"""A 2D lidar like the seed's RPLIDAR A1M8: 360 beams at ~1°, 0.15–12 m, 10 Hz.

The scan plane sits ``mount.z_m`` (0.527 m) above the floor, so anything lower — a bench,
a cart, a person's feet — is invisible to it; that is the seed's real failure mode and
the simulator keeps it. People show up as their two legs.

Noise: Gaussian range noise of ``noise_fraction`` of the range (plus a floor), and each
beam drops out (no return, ``inf``) with ``dropout_probability``. Motion during one
revolution is ignored (the whole scan is taken at one pose).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sage_robot.core.msgs import LaserScan
from sage_robot.sim.raycast import GridRaycaster, ray_boxes, ray_circles

BEAMS = 360
RANGE_MIN_M = 0.15
RANGE_MAX_M = 12.0
RATE_HZ = 10.0
NOISE_FRACTION = 0.01  # 1 sigma, of the range (the A1M8's datasheet accuracy is 1–2.5 %)
NOISE_FLOOR_M = 0.003
DROPOUT_PROBABILITY = 0.01
FRAME_ID = "laser"


@dataclass(frozen=True)
class LidarSpec:
    beams: int = BEAMS
    range_min_m: float = RANGE_MIN_M
    range_max_m: float = RANGE_MAX_M
    rate_hz: float = RATE_HZ
    noise_fraction: float = NOISE_FRACTION
    noise_floor_m: float = NOISE_FLOOR_M
    dropout_probability: float = DROPOUT_PROBABILITY
    mount_x_m: float = 0.1466  # forward of base_link
    mount_y_m: float = 0.0
    mount_z_m: float = 0.527  # scan-plane height above the floor
    mount_yaw_rad: float = 0.0

    @property
    def angle_min(self) -> float:
        return -math.pi

    @property
    def angle_increment(self) -> float:
        return 2.0 * math.pi / self.beams

    def angles(self) -> np.ndarray:
        """Beam angles in the laser frame (rad), from -pi, counter-clockwise."""
        return self.angle_min + self.angle_increment * np.arange(self.beams)


class Lidar:
    """Turns the world's geometry into noisy ranges."""

    def __init__(self, spec: LidarSpec, raycaster: GridRaycaster, rng: np.random.Generator) -> None:
        self.spec, self.raycaster, self.rng = spec, raycaster, rng
        self._angles = spec.angles()

    def pose(self, robot: tuple[float, float, float]) -> tuple[float, float, float]:
        """The laser frame's pose in the map frame."""
        x, y, th = robot
        c, s = math.cos(th), math.sin(th)
        sp = self.spec
        return (
            x + c * sp.mount_x_m - s * sp.mount_y_m,
            y + s * sp.mount_x_m + c * sp.mount_y_m,
            th + sp.mount_yaw_rad,
        )

    def true_ranges(
        self, robot: tuple[float, float, float], legs: np.ndarray, tall_boxes: np.ndarray
    ) -> np.ndarray:
        """Noise-free ranges (m, inf = nothing) against walls, legs and boxes as tall as the plane."""
        lx, ly, lth = self.pose(robot)
        world_angles = lth + self._angles
        r = self.raycaster.cast(lx, ly, world_angles, self.spec.range_max_m)
        if legs.size:
            r = np.minimum(r, ray_circles(lx, ly, world_angles, legs))
        if tall_boxes.size:
            r = np.minimum(r, ray_boxes(lx, ly, world_angles, tall_boxes)[0])
        return r

    def measure(self, true_ranges: np.ndarray) -> np.ndarray:
        """Add range noise and dropouts; out-of-range readings become inf (float32)."""
        sp = self.spec
        finite = np.isfinite(true_ranges)
        sigma = sp.noise_fraction * np.where(finite, true_ranges, 0.0) + sp.noise_floor_m
        noisy = true_ranges + self.rng.standard_normal(true_ranges.shape) * sigma
        drop = self.rng.random(true_ranges.shape) < sp.dropout_probability
        bad = ~finite | drop | (noisy < sp.range_min_m) | (noisy > sp.range_max_m)
        return np.where(bad, np.inf, noisy).astype(np.float32)

    def scan(
        self, stamp: float, robot: tuple[float, float, float], legs: np.ndarray, tall_boxes: np.ndarray
    ) -> LaserScan:
        ranges = self.measure(self.true_ranges(robot, legs, tall_boxes))
        sp = self.spec
        return LaserScan(
            stamp,
            FRAME_ID,
            sp.angle_min,
            sp.angle_increment,
            sp.range_min_m,
            sp.range_max_m,
            ranges,
            1.0 / sp.rate_hz,
        )
