"""The ``localization`` node: AMCL on ``/scan`` + ``/odom`` (optionally EKF-fused with the IMU).

Publishes ``/amcl_pose`` (with covariance) after each filter update, the map→odom
correction on ``MAP_ODOM`` after each scan, and ``/localization/health`` (how well the
scan fits the map at the estimate; lost below ``nav.lost_below``). The initial pose is
the place ``nav.initial_place``; ``/initialpose`` resets it; the ``GLOBAL_LOCALIZATION``
service relocalizes over the free space connected to the places (``amcl_global``; the next
few scans update the filter even without motion). Health carries ``spread_m`` and the
number of ``hypotheses`` still alive: after a global relocalization the cloud is only
converged when one place is left. With ``nav.refine_pose``, a converged estimate is
refined by scan matching (``scanmatch``) after each filter update, and that pose is what
``/amcl_pose`` and the map→odom correction report. Filter updates run in a worker thread.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections import deque
from typing import Any

import numpy as np

from sage_robot.core import topics
from sage_robot.core.geometry import compose, inverse, relative
from sage_robot.core.msgs import Imu, LaserScan, Odometry, Pose2D, PoseStamped, PoseWithCovariance
from sage_robot.core.msgs.nav import LocalizationHealth
from sage_robot.core.node import Node
from sage_robot.nav.amcl import ParticleFilter, scan_fit
from sage_robot.nav.ekf import YawRateEkf
from sage_robot.nav.mapdata import load_for
from sage_robot.nav.scanmatch import SignedDistanceField, refine

Pose = tuple[float, float, float]
Fix = tuple[Pose, Pose]  # a refined map pose and the odometry pose it was taken at

HEALTH_WINDOW = 5  # scans averaged into the health score
HEALTH_SCORE_DECIMALS = 2  # the published score's resolution (0.01): at rest it then repeats
#   itself, and other processes get it when it changes or every 0.5 s (bus.zenoh.repeat_every_s)
FORCED_UPDATES_AFTER_RESET = 8  # filter updates without motion after a global relocalization
FORCED_UPDATE_PERIOD_S = 0.3  # how often those forced updates may run (s)
MIN_INITIAL_SIGMA_XY_M = 0.05
MIN_INITIAL_SIGMA_YAW_RAD = 0.05
UPDATE_LATENCY_S = 0.1  # time a filter update may take (a 10 Hz scan period): in the
#   simulator time runs on beside it and the update lands exactly this much later (s)
REFINE_SPREAD_M = 0.3  # refine the pose by scan matching only once the cloud is this tight (m)


class LocalizationNode(Node):
    name = "localization"
    _sdf: SignedDistanceField | None = None  # the scan matcher's field, built after start-up

    async def _prepare_region(self) -> None:
        """Where global localization may look (~0.3 s of CPU) and the scan matcher's distance
        field (~1.5 s on the shipped map), worked out after start-up so the node is running
        (and tracking from its initial place) meanwhile."""
        await self.clock.offload(lambda: self.pf.region)
        if self.settings.nav.refine_pose:
            self._sdf = await self.clock.offload(SignedDistanceField, self.data.grid)

    async def setup(self) -> None:
        nav, lidar = self.settings.nav, self.settings.robot.lidar
        self.data = load_for(self.settings)
        seeds = [(p.pose.x, p.pose.y) for p in self.data.places]
        self.pf = ParticleFilter(self.data.grid, np.random.default_rng(nav.seed), nav.min_particles,
                                 nav.max_particles, (lidar.x_m, lidar.y_m, lidar.yaw_rad), nav.laser_beams,
                                 seeds=seeds)
        self._lock = asyncio.Lock()
        self._odom: Pose | None = None
        self._ekf = YawRateEkf() if nav.use_ekf else None
        self._scores: deque[float] = deque(maxlen=HEALTH_WINDOW)
        self._forced = 0
        self._last_forced = -math.inf
        self._map_pose: Pose | None = None
        self._sdf = None
        self._fix: Fix | None = None
        self.refined = 0  # filter updates whose pose the scan matcher refined
        self.health: LocalizationHealth | None = None
        self.update_times: deque[float] = deque(maxlen=200)
        self._global_pending = nav.initial_place not in self.data.places
        if self._global_pending:
            self.log.warning("initial place unknown: localizing globally", place=nav.initial_place)
        else:
            p = self.data.places.get(nav.initial_place).pose
            self.pf.set_pose(p.x, p.y, p.theta)
        self._cloud = await self.clock.offload(self._cloud_stats)
        self.subscribe(topics.ODOM, Odometry, self._on_odom, maxsize=50)
        if self._ekf is not None:
            self.subscribe(topics.IMU, Imu, self._on_imu, maxsize=50)
        self.subscribe(topics.INITIAL_POSE, PoseWithCovariance, self._on_initial_pose)
        self._scans = self.subscribe(topics.SCAN, LaserScan, maxsize=1)
        self.bus.serve(topics.GLOBAL_LOCALIZATION, self._global_service)
        self.spawn(self._scan_loop(), "localization.scans")
        self.spawn(self._prepare_region(), "localization.region")

    # ------------------------------------------------------------ inputs
    def _on_odom(self, msg: Odometry) -> None:
        if self._ekf is None:
            self._odom = msg.pose.as_tuple()
            return
        if self._odom is None:
            self._ekf.reset(*msg.pose.as_tuple())
        self._ekf.odom(msg.stamp, msg.twist.linear_x, msg.twist.angular_z)
        self._odom = self._ekf.pose

    def _on_imu(self, msg: Imu) -> None:
        if self._ekf is not None and self._odom is not None:
            self._ekf.imu(msg.stamp, msg.angular_velocity[2])
            self._odom = self._ekf.pose

    async def _on_initial_pose(self, msg: PoseWithCovariance) -> None:
        cov = msg.covariance
        sxy = max(math.sqrt(max(cov[0], cov[4], 0.0)), MIN_INITIAL_SIGMA_XY_M)
        syaw = max(math.sqrt(max(cov[8], 0.0)), MIN_INITIAL_SIGMA_YAW_RAD)
        async with self._lock:
            self.pf.set_pose(msg.pose.x, msg.pose.y, msg.pose.theta, sxy, syaw)
            self.pf._odom_ref = None
            self._fix = None
            self._cloud = await self.clock.offload(self._cloud_stats)
            self._scores.clear()
            self._forced = FORCED_UPDATES_AFTER_RESET
        self.log.info("initial pose set", x=round(msg.pose.x, 2), y=round(msg.pose.y, 2))

    async def _global_service(self, _request: Any) -> LocalizationHealth:
        """Relocalize over the whole map from the next scan; answers the health before it."""
        self._global_pending = True
        if self.health is not None:
            return self.health
        async with self._lock:  # the filter is not read while an update runs in its thread
            return LocalizationHealth(self.clock.now(), 0.0, True, self.pf.count)

    # ------------------------------------------------------------ the filter
    async def _scan_loop(self) -> None:
        async for scan in self._scans:
            if self._odom is None:
                continue
            await self._process(scan, self._odom)

    async def _process(self, scan: LaserScan, odom: Pose) -> None:
        angles = scan.angles.astype(np.float64)
        ranges = np.asarray(scan.ranges, dtype=np.float64)
        async with self._lock:
            if self._global_pending:
                self._global_pending = False
                await self.clock.offload(self.pf.global_localization, (angles, ranges, scan.range_max))
                self._cloud = await self.clock.offload(self._cloud_stats)
                self._forced, self._scores = FORCED_UPDATES_AFTER_RESET, deque(maxlen=HEALTH_WINDOW)
                self._fix = None
                self.log.info("global localization started", particles=self.pf.count)
            now = self.clock.now()
            force = self._forced > 0 and now - self._last_forced >= FORCED_UPDATE_PERIOD_S
            if force or self.pf.moved_enough(odom):
                update = await self.clock.offload(self._update, odom, angles, ranges, scan.range_max,
                                                  force, latency_s=UPDATE_LATENCY_S)
                if update is not None and force:
                    self._forced -= 1
                    self._last_forced = now
                if update is not None:
                    self._cloud, self._fix = update
                    self._publish_pose(scan.stamp)
            pose = compose(self._fix[0], relative(self._fix[1], odom)) if self._fix else self.pf.pose_at(odom)
        self._map_pose = pose
        correction = compose(pose, inverse(odom))
        self.bus.publish(topics.MAP_ODOM, PoseStamped(scan.stamp, "map", Pose2D(*correction)))
        self._publish_health(scan, pose, angles, ranges)

    def _cloud_stats(self) -> tuple[float, int]:
        """Spread (m) and hypothesis count of the cloud: it changes only with filter updates,
        so this runs once per update, in the worker thread, not on every scan."""
        return self.pf.spread_m(), max(1, len(self.pf.hypotheses()))

    def _update(self, odom: Pose, angles: np.ndarray, ranges: np.ndarray, range_max: float,
                force: bool) -> tuple[tuple[float, int], Fix | None] | None:
        """One filter update (worker thread): the cloud's stats and the refined pose with it, or
        None when the filter did not update. The node's own fields are set by the caller, on
        the event loop, when the result is handed over."""
        t0 = time.perf_counter()
        updated = self.pf.update(odom, angles, ranges, range_max, force)
        self.update_times.append(time.perf_counter() - t0)
        if not updated:
            return None
        cloud = self._cloud_stats()
        return cloud, self._refine(cloud, odom, angles, ranges, range_max)

    def _refine(self, cloud: tuple[float, int], odom: Pose, angles: np.ndarray, ranges: np.ndarray,
                range_max: float) -> Fix | None:
        """The filter's estimate placed on the map by scan matching, when the cloud is one tight
        hypothesis (a split cloud is not refined: the matcher would only polish one guess)."""
        spread, hypotheses = cloud
        if self._sdf is None or spread > REFINE_SPREAD_M or hypotheses > 1:
            return None
        e, lidar = self.pf.estimate(), self.settings.robot.lidar
        fix = refine(self._sdf, (e.x, e.y, e.theta), (lidar.x_m, lidar.y_m, lidar.yaw_rad), angles, ranges,
                     range_max)
        if fix is None:
            return None
        self.refined += 1
        return (fix.x, fix.y, fix.theta), odom

    def _publish_pose(self, stamp: float) -> None:
        e = self.pf.estimate()
        x, y, theta = self._fix[0] if self._fix else (e.x, e.y, e.theta)
        msg = PoseWithCovariance(stamp, "map", Pose2D(x, y, theta), e.covariance)
        self.bus.publish(topics.AMCL_POSE, msg)

    def _publish_health(self, scan: LaserScan, pose: Pose, angles: np.ndarray, ranges: np.ndarray) -> None:
        nav, lidar = self.settings.nav, self.settings.robot.lidar
        fit = scan_fit(self.pf.field, pose, (lidar.x_m, lidar.y_m, lidar.yaw_rad), angles, ranges,
                       scan.range_max, nav.health_tolerance_m)
        if not math.isnan(fit):
            self._scores.append(fit)
        score = float(np.mean(self._scores)) if self._scores else 0.0
        lost = len(self._scores) > 0 and score < nav.lost_below
        spread, hypotheses = self._cloud
        self.health = LocalizationHealth(scan.stamp, round(score, HEALTH_SCORE_DECIMALS), lost, self.pf.count,
                                         round(spread, 3), hypotheses)
        self.bus.publish(topics.LOC_HEALTH, self.health)

    async def teardown(self) -> None:
        self.bus.unserve(topics.GLOBAL_LOCALIZATION)

    def stats(self) -> dict[str, Any]:
        times = sorted(self.update_times)
        return {
            "particles": self.pf.count,
            "updates": self.pf.updates,
            "refined": self.refined,
            "update_ms_median": round(1000 * times[len(times) // 2], 2) if times else None,
            "health": round(self.health.score, 3) if self.health else None,
        }
