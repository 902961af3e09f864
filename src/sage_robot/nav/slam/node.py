"""The ``slam`` node: online mapping from ``/scan`` + ``/odom`` while an operator drives.

- subscribes ``/scan`` (newest only: a scan that arrives while one is being matched replaces
  the waiting one) and ``/odom`` (the pose at each scan's stamp is interpolated), and with
  ``slam.use_imu`` ``/imu/data``: while the gyro's samples come, each odometry step turns by
  the gyro's heading instead of the wheels' (:mod:`sage_robot.nav.slam.gyro`);
- publishes the growing map on ``/map`` (latched) every ``slam.map_period_s`` (1 s) when it
  changed, and a :class:`SlamProgress` on ``/slam/progress`` (latched) and the map->odom
  correction on ``/localization/map_odom`` (as localization does) after each scan;
- offers ``/slam/save`` (:class:`SaveMapRequest` → :class:`SaveMapReply`).

Matching and map building run in a worker thread so the event loop never stalls. The laser
mount comes from the profile (``robot.lidar``). Map files go to ``ctx.resources[OUT_DIR_RESOURCE]``
when set, else ``slam.out_dir``, else ``<state dir>/maps``. The engine's thresholds come from
the profile's ``slam`` section (:func:`slam_config`).
"""

from __future__ import annotations

import asyncio
import bisect
import dataclasses
import math
from collections import deque
from pathlib import Path
from typing import Any

import numpy as np

from sage_robot.core import topics
from sage_robot.core.bus import Topic
from sage_robot.core.config.areas import SlamSettings
from sage_robot.core.geometry import compose, inverse
from sage_robot.core.msgs import Imu, LaserScan, OccupancyGrid, Odometry, Pose2D, PoseStamped
from sage_robot.core.node import Node
from sage_robot.core.paths import state_dir
from sage_robot.core.resources import ResourceKey, Resources
from sage_robot.nav.slam.engine import Slam, SlamConfig
from sage_robot.nav.slam.gyro import GyroHeading, GyroOdometry
from sage_robot.nav.slam.messages import SaveMapReply, SaveMapRequest, SlamProgress
from sage_robot.nav.slam.points import Pose, Scan
from sage_robot.nav.slam.store import mapper_for, save_session
from sage_robot.nav.slam.tuning import noisy_lidar_config

ODOM_HISTORY = 50  # odometry messages kept to interpolate at scan times (1 s at 50 Hz)
IMU_QUEUE = 100  # gyro samples that may wait for the node (1 s at 100 Hz)
SLAM_PROGRESS = Topic("/slam/progress", SlamProgress, latched=True)
SLAM_SAVE = "/slam/save"  # service: SaveMapRequest -> SaveMapReply
OUT_DIR_RESOURCE: ResourceKey[str | Path] = ResourceKey("slam_out_dir")  # where /slam/save writes by default
# (x, y, theta) of the first scan
INITIAL_POSE_RESOURCE: ResourceKey[tuple[float, float, float]] = ResourceKey("slam_initial_pose", tuple)
AUTOSAVE_RESOURCE = ResourceKey("slam_autosave", str)  # map name to save under when the node stops
SAVED_RESOURCE: ResourceKey[dict[str, str]] = ResourceKey("slam_saved", dict)  # the autosave's paths


@dataclasses.dataclass(frozen=True)
class MapJob:
    """Scans to draw into the grid: all of them again (``rebuild``) or the ones from ``start``."""

    rebuild: bool
    poses: list[Pose]
    scans: list[Scan]
    version: int  # the graph's version they are drawn at
    start: int  # the first map scan's index
    count: int  # map scans drawn once this is done


class SlamNode(Node):
    name = "slam"

    async def setup(self) -> None:
        lidar = self.settings.robot.lidar
        self.laser = (lidar.x_m, lidar.y_m, lidar.yaw_rad)
        initial = self.ctx.resources.get(INITIAL_POSE_RESOURCE, (0.0, 0.0, 0.0))
        self.config = self.settings.slam
        self.slam = Slam(slam_config(self.config), initial_pose=initial)
        self.mapper = mapper_for(self.slam, self.config.resolution_m)
        self._mapped_scans = 0  # map scans drawn into the grid
        self._map_version = 0  # the graph's version the grid was drawn at
        self._last_rebuild = -math.inf  # clock time (s) of the last full redraw
        self._lock = asyncio.Lock()  # the SLAM state: one scan, save or map snapshot at a time
        self._map_lock = asyncio.Lock()  # the grid: drawn outside the SLAM lock
        self._odom: Odometry | None = None
        self.scans = 0
        self.bus.declare(topics.MAP, OccupancyGrid, latched=True)
        self.bus.declare(SLAM_PROGRESS, latched=True)  # the web page asks for the last
        self._odom_history: deque[tuple[float, Pose]] = deque(maxlen=ODOM_HISTORY)
        self.subscribe(topics.ODOM, Odometry, self._on_odom, maxsize=ODOM_HISTORY)
        self._gyro = GyroHeading()
        self._fused = GyroOdometry()
        self.gyro_scans = 0  # scans whose odometry step the gyro turned
        if self.config.use_imu:
            self.subscribe(topics.IMU, Imu, self._on_imu, maxsize=IMU_QUEUE)
        self._scan_sub = self.subscribe(topics.SCAN, LaserScan, maxsize=1)
        self.bus.serve(SLAM_SAVE, self._on_save)
        self.spawn(self._scan_loop(), name="slam.scans")
        self.every(self.config.map_period_s, self._publish_map, name="slam.map")

    async def teardown(self) -> None:
        self.bus.unserve(SLAM_SAVE)
        name = self.ctx.resources.get(AUTOSAVE_RESOURCE)
        if not name or not getattr(self, "slam", None) or not self.slam.keyframes:
            return
        try:
            async with self._lock, self._map_lock:
                paths = await self.clock.offload(self._save, self.out_dir(), name)
            self.ctx.resources[SAVED_RESOURCE] = paths
            self.log.info("map saved on exit", **paths)
        except Exception as exc:  # teardown must not raise
            self.log.error("could not save the map on exit", error=str(exc))

    def _on_odom(self, msg: Odometry) -> None:
        self._odom = msg
        self._odom_history.append((msg.stamp, msg.pose.as_tuple()))

    def _on_imu(self, msg: Imu) -> None:
        self._gyro.add(msg.stamp, msg.angular_velocity[2])

    async def _scan_loop(self) -> None:
        async for msg in self._scan_sub:
            if self._odom is None:
                continue  # no odometry yet: nothing to predict from
            odom = odom_at(list(self._odom_history), msg.stamp)
            fused, gyro = self._fused.step(odom, self._gyro.at(msg.stamp))
            scan = Scan(np.asarray(msg.ranges), msg.angles, msg.range_min, msg.range_max, self.laser)
            async with self._lock:
                result = await self.clock.offload(self._process, msg.stamp, fused, scan, gyro)
            self.scans += 1
            self.gyro_scans += gyro
            x, y, th = result.pose
            # map -> odom, as localization publishes it: pages draw the robot on the growing map.
            correction = Pose2D(*compose(result.pose, inverse(odom)))
            self.bus.publish(topics.MAP_ODOM, PoseStamped(msg.stamp, "map", correction))
            self.bus.publish(
                SLAM_PROGRESS,
                SlamProgress(
                    self.clock.now(),
                    self.scans,
                    len(self.slam.keyframes),
                    self.slam.loop_closures,
                    round(result.score, 4),
                    Pose2D(x, y, th),
                    self.slam.optimizations,
                ),
            )

    def _process(self, stamp: float, odom: Pose, scan: Scan, gyro: bool) -> Any:
        return self.slam.add_scan(stamp, odom, scan, gyro)

    def _map_job(self, full: bool) -> MapJob | None:
        """What the grid needs from the SLAM state (taken under the SLAM lock, cheap): a full
        redraw at the optimised poses when the graph changed (at most every
        ``map_rebuild_period_s``, unless ``full``), else the map scans it lacks; None: nothing."""
        slam, now = self.slam, self.clock.now()
        stale = slam.map_version != self._map_version
        if stale and (full or now - self._last_rebuild >= self.config.map_rebuild_period_s):
            self._last_rebuild = now
            return MapJob(True, *slam.map_scans(), slam.map_version, 0, slam.map_scan_count)
        start = self._mapped_scans
        if slam.map_scan_count > start:
            return MapJob(False, *slam.map_scans(start), self._map_version, start, slam.map_scan_count)
        return None

    def _draw(self, job: MapJob) -> None:
        if job.rebuild:
            self.mapper.rebuild(job.poses, job.scans)
        elif job.start == self._mapped_scans:  # else a save drew them meanwhile
            self.mapper.integrate_many(job.poses, job.scans)
        else:
            return
        self._map_version, self._mapped_scans = job.version, job.count

    async def _publish_map(self) -> None:
        async with self._lock:
            job = self._map_job(full=False)
        if job is None:
            return
        async with self._map_lock:  # scans go on being matched while the grid is drawn
            await self.clock.offload(self._draw, job)
            grid = await self.clock.offload(self.mapper.to_grid, self.clock.now())
        self.bus.publish(topics.MAP, grid)

    async def _on_save(self, req: SaveMapRequest) -> SaveMapReply:
        out = Path(req.directory) if req.directory else self.out_dir()
        async with self._lock, self._map_lock:
            paths = await self.clock.offload(self._save, out, req.name)
        self.log.info("map saved", **paths)
        return SaveMapReply(paths["yaml"], paths["pgm"], paths["graph"], paths["trajectory"])

    def _save(self, out: Path, name: str) -> dict[str, str]:
        self.slam.finish()  # the keyframes since the last loop closure, optimised with the rest
        job = self._map_job(full=True)
        if job is not None:
            self._draw(job)
        return save_session(self.slam, out, name, self.mapper.to_grid(self.clock.now()))

    def out_dir(self) -> Path:
        return maps_dir(self.ctx.resources, self.config)

    def stats(self) -> dict[str, Any]:
        return {
            "scans": self.scans,
            "gyro_scans": self.gyro_scans,
            "keyframes": len(self.slam.keyframes),
            "loop_closures": self.slam.loop_closures,
            "odometry_slips": self.slam.odometry_slips,
            "doubtful_turns": self.slam.doubtful_turns,
            "score": round(self.slam.last_score, 3),
        }


def maps_dir(resources: Resources, settings: SlamSettings) -> Path:
    """Where the slam node saves maps: ``OUT_DIR_RESOURCE``, else ``slam.out_dir``, else
    ``<state dir>/maps`` (the web server lists and tours the maps found there)."""
    out = resources.get(OUT_DIR_RESOURCE)
    return Path(out or settings.out_dir or state_dir() / "maps")


def slam_config(settings: SlamSettings) -> SlamConfig:
    """The engine's configuration with the profile's ``slam`` section applied (with range
    noise, the settings for a low-cost lidar: :mod:`sage_robot.nav.slam.tuning`)."""
    return dataclasses.replace(
        noisy_lidar_config(SlamConfig(), settings.range_noise_fraction),
        max_range_m=settings.max_range_m,
        keyframe_dist_m=settings.keyframe_dist_m,
        keyframe_angle_rad=settings.keyframe_angle_rad,
        loop_radius_m=settings.loop_radius_m,
        loop_min_travel_m=settings.loop_min_travel_m,
        loop_min_score=settings.loop_min_score,
        loop_min_inliers=settings.loop_min_inliers,
    )


def odom_at(history: list[tuple[float, Pose]], stamp: float) -> Pose:
    """The odometry pose at ``stamp`` (s), interpolated between the messages around it; the
    nearest end of ``history`` (sorted by stamp) outside it."""
    stamps = [t for t, _ in history]
    k = bisect.bisect_left(stamps, stamp)
    if k == 0:
        return history[0][1]
    if k == len(history):
        return history[-1][1]
    (t0, a), (t1, b) = history[k - 1], history[k]
    f = (stamp - t0) / (t1 - t0) if t1 > t0 else 1.0
    dth = math.remainder(b[2] - a[2], 2 * math.pi)
    return (a[0] + f * (b[0] - a[0]), a[1] + f * (b[1] - a[1]), math.remainder(a[2] + f * dth, 2 * math.pi))
