"""Online graph SLAM: scan-to-local-map matching, keyframes, loop closures, pose-graph optimisation.

For each scan (robot-frame ranges + the odometry pose it was taken at):

1. predict the pose from the odometry increment since the previous scan;
2. match the scan against a local map made of the last ``local_keyframes`` keyframes: a
   correlative search around the prediction, then point-to-line ICP (:mod:`matcher`);
3. when the robot has moved ``keyframe_dist_m`` or turned ``keyframe_angle_rad`` since the
   last keyframe, the scan becomes a keyframe: a pose-graph node with a scan-match edge and a
   (weak) odometry edge to the previous keyframe;
4. a new keyframe near an old part of the trajectory (within ``loop_radius_m``, at least
   ``loop_min_travel_m`` of travel ago) is matched against a submap of the old keyframes with a
   wide correlative search; a match whose score and inlier fraction pass the thresholds
   becomes a loop-closure edge, and the graph is optimised (:mod:`posegraph`).

Every scan's pose is kept relative to its keyframe, so the whole trajectory follows the
optimised keyframes. Poses are (x, y m; theta rad) in the map frame, whose origin is the
first scan's pose (``initial_pose``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from sage_robot.core.geometry import compose, relative
from sage_robot.nav.slam.dynamic import small_foreground, supported
from sage_robot.nav.slam.endwall import EndWallRuler
from sage_robot.nav.slam.matcher import Match, MatchConfig, PointMap, smooth_normals
from sage_robot.nav.slam.odomcal import OdometryCalibration
from sage_robot.nav.slam.points import Pose, Scan, normals, rotate, transform, voxel_filter, voxel_indices
from sage_robot.nav.slam.posegraph import KIND_LOOP, KIND_ODOM, KIND_SCAN, Edge, PoseGraph

MIN_SCAN_POINTS = 20  # a scan with fewer hits is dead-reckoned
DOUBTFUL_INLIERS = 0.6  # a match this poor makes the tracker try other motion guesses
SEARCH_PRIOR_SCALE = 2.0  # the correlative search's prior is this much wider than ICP's
GLITCH_MARGIN = 0.05  # another guess must match this much better (inlier fraction) to win
# A gyro-turned odometry edge whose x, y step disagrees with the scan-matched one by more than
# this many of its sigmas is a wheel slip: the edge falls back to the wheels' weak noise
SLIP_SIGMAS = 10.0
MIN_TRAVEL_M = 0.05  # a submap edge shorter than this keeps its information along the travel


@dataclass(frozen=True)
class SlamConfig:
    max_range_m: float = 30.0  # hits beyond this are ignored (and cleared only this far)
    scan_voxel_m: float = 0.05  # scan points used for matching: one per cell of this size
    map_voxel_m: float = 0.03  # local map point spacing
    keyframe_dist_m: float = 0.3  # a new keyframe after this much travel...
    keyframe_angle_rad: float = 0.2  # ...or this much turning
    local_keyframes: int = 25  # keyframes in the local map
    # The scan was matched against the whole local map, so its match can also tie the new
    # keyframe to these older keyframes of that map (counted back from the previous one):
    # an odometry bias then cannot bend the chain one small step at a time. Such an edge holds
    # the chain straight (across the travel and in heading) but says nothing about its length:
    # the older keyframe was placed by the same tracker, so the edge's travel would only repeat
    # the chain's own drift (docs/slam.md, "Submap edges hold the chain straight"). The corridor
    # fixes below (issue #23) are off by default: on the MIT CSAIL log, all of them together
    # took the relation error from 0.027 to 0.087 m (26 loops closed instead of 74); the
    # simulation bench turns them on (bench/slam_sim.slam_config).
    submap_edge_strides: tuple[int, ...] = ()
    search_xy_m: float = 0.25  # correlative search window around the prediction (±)
    search_theta_rad: float = 0.3  # (±): wheel odometry turns badly (MIT CSAIL: 0.1 rad per 0.4 s)
    search_theta_step_rad: float = 0.01
    min_track_inliers: float = 0.3  # below this the match is not trusted: dead-reckon
    # Pull of the odometry prediction in ICP: it only matters along directions the scan does
    # not pin down (a long bare corridor); base + fraction of the step's translation.
    prior_sigma_xy_m: float = 0.02
    prior_sigma_xy_fraction: float = 0.1
    prior_sigma_theta_rad: float = 0.2  # wheel odometry turns badly: keep this weak
    # A step whose turn a gyro measured (add_scan(..., gyro=True); :mod:`gyro`): its heading
    # noise, for the ICP prior and odometry edges instead of the wheels' weak ones above and
    # below: this base (rad) plus this fraction of the step's turn (the gyro's scale error).
    gyro_sigma_theta_rad: float = 0.002
    gyro_sigma_turn_fraction: float = 0.02
    # The odometry edge's x, y noise between keyframes the gyro turned: base (m) + fraction of
    # the distance (a calibrated odometry is good to a centimetre a metre; with the wheels'
    # heading alone stiff edges made drives slide: docs/slam.md, "Odometry edges")
    gyro_odom_sigma_xy_m: float = 0.05
    gyro_odom_sigma_xy_fraction: float = 0.2
    # > 0 (with calibrate_odometry): once the calibration's scale is known to this standard
    # error (a fraction, OdometryCalibration.scale_error), the wheel-turned odometry edges get
    # those stiff x, y sigmas too (their heading keeps the wheels' weak noise), and every
    # optimisation measures their x, y again with the calibration. Along a bare corridor only
    # the odometry knows the travel; with weak edges the map took the tracker's, which wanders
    # four times more; with a scale not yet known they carry its error instead (docs/slam.md,
    # "The wheels alone"). Before that, an edge's x, y sigma is the stiff one times the scale's
    # standard error over this gate, at most the wheels' weak one: stiffer as the scale becomes
    # known, not measured again. A slip still falls back to the weak noise (SLIP_SIGMAS).
    wheel_travel_scale_error: float = 0.0
    # > 0: a doubtful match (inliers below DOUBTFUL_INLIERS) whose heading is this far (rad) from
    # the odometry's prediction is not believed, and the scan is dead-reckoned: the odometry
    # turns a few thousandths of a radian off in a scan, and a scan that fits the local map
    # poorly fits a turned copy of it about as well (a robot turning in a doorway, docs/slam.md,
    # "The wheels alone")
    doubtful_turn_gate_rad: float = 0.0
    odom_sigma_xy_m: float = 0.05  # odometry edge noise: base + fraction of the motion
    odom_sigma_theta_rad: float = 0.03
    odom_sigma_fraction: float = 0.2
    loop_radius_m: float = 6.0  # candidates within this distance of the new keyframe
    loop_min_travel_m: float = 12.0  # ...and at least this far back along the trajectory
    loop_search_xy_m: float = 2.0  # loop-closure correlative window (±)
    loop_search_theta_rad: float = 0.35
    loop_search_theta_step_rad: float = 0.02
    loop_submap_keyframes: int = 12  # old keyframes each side of the candidate in its submap
    loop_min_score: float = 0.55  # mean likelihood a loop closure needs
    loop_min_inliers: float = 0.65  # fraction of points within inlier_m a loop closure needs
    loop_distinct_m: float = 0.5  # another match this far away...
    loop_max_ambiguity: float = 0.85  # ...scoring this fraction of the best: ambiguous, rejected
    loop_max_chi: float = 8.0  # a loop edge's Mahalanobis error after optimising must stay below this
    loop_information_scale: float = 0.5  # a loop edge counts this much of a scan-match edge
    loop_every_keyframes: int = 2  # try a loop closure every this many keyframes
    calibrate_odometry: bool = False  # learn the odometry's scale and heading drift (odomcal)
    # ...also from the lidar's straight-ahead range while the gyro holds the heading (endwall):
    # a ruler without the scan matcher's travel bias (without a gyro, judged on the tracked
    # heading, it read the depot's and the warehouse's travel worse: docs/slam.md, "The wheels alone")
    end_wall_ruler: bool = False
    oriented_normals: bool = False  # match only map surfaces that face the scan's sensor
    # > 0: the local map's normals are fitted again on the merged keyframes, to this many
    # neighbours within map_normal_radius_m (for a noisy lidar; 0: each keyframe's own normals)
    map_normal_neighbours: int = 0
    map_normal_radius_m: float = 0.5
    # > 1: a local-map point needs points of this many keyframes in its map_support_cell_m
    # cell (walking people's legs are somewhere else in every keyframe: they drop out)
    map_min_support: int = 1
    map_support_cell_m: float = 0.15
    # > 0: returns of foreground objects no wider than this (m: legs) are left out of matching
    drop_small_objects_m: float = 0.0
    # The occupancy grid is made of the keyframes' scans and, between keyframes, of one
    # tracked scan per this much travel or turning (a wall seen only between two keyframes,
    # through a door on the way past, is mapped too); 0: keyframes only.
    map_scan_dist_m: float = 0.1
    map_scan_angle_rad: float = 0.1
    match: MatchConfig = field(default_factory=MatchConfig)

    def __post_init__(self) -> None:  # a saved session's JSON gives lists back
        object.__setattr__(self, "submap_edge_strides", tuple(self.submap_edge_strides))


def _across_travel(info: np.ndarray, z: Pose) -> np.ndarray:
    """``info`` (x, y, theta) without its information along the translation of ``z``."""
    dist = math.hypot(z[0], z[1])
    if dist < MIN_TRAVEL_M:  # a turn on the spot: no direction of travel
        return info
    u = np.array([z[0] / dist, z[1] / dist, 0.0])
    p = np.eye(3) - np.outer(u, u)
    out: np.ndarray = p @ info @ p
    return out


@dataclass
class Keyframe:
    stamp: float
    odom: Pose
    scan: Scan
    points: np.ndarray  # robot frame, map_voxel_m filtered
    travel_m: float  # trajectory length up to here
    normals: np.ndarray | None = None  # of the points, robot frame (computed once)
    # scans tracked after this keyframe, for the occupancy grid: (pose relative to it, scan)
    map_scans: list[tuple[Pose, Scan]] = field(default_factory=list)

    def point_normals(self) -> np.ndarray:
        """Unit normals, each turned to face the laser that saw its point (robot frame)."""
        if self.normals is None:
            if len(self.points):
                nrm = normals(self.points, cKDTree(self.points))
                toward = np.asarray(self.scan.laser[:2]) - self.points
                self.normals = np.where((np.einsum("ij,ij->i", nrm, toward) < 0)[:, None], -nrm, nrm)
            else:
                self.normals = self.points
        return self.normals


@dataclass(frozen=True)
class StepResult:
    pose: Pose
    score: float
    inliers: float
    keyframe: bool
    loop_closed: bool


@dataclass
class _TrajectoryEntry:
    stamp: float
    keyframe: int
    offset: Pose  # pose relative to the keyframe


class Slam:
    def __init__(self, config: SlamConfig | None = None, initial_pose: Pose = (0.0, 0.0, 0.0)) -> None:
        self.config = config or SlamConfig()
        self.initial_pose = initial_pose
        self.graph = PoseGraph()
        self.keyframes: list[Keyframe] = []
        self.trajectory: list[_TrajectoryEntry] = []
        self.pose: Pose = initial_pose
        self.last_score = 0.0
        self.loop_attempts = 0
        self.loops_rejected = 0  # matched, but the optimised graph disagreed with them
        self.odometry_slips = 0  # gyro-turned odometry edges weakened: the wheels slipped
        self._kf_pose_before: Pose = initial_pose
        self.optimizations = 0
        self.map_version = 0  # bumps when keyframe poses change (after an optimisation)
        self._last_odom: Pose | None = None
        self._last_step: Pose = (0.0, 0.0, 0.0)  # estimated motion between the last two scans
        self._step_dist = 0.0  # odometry translation since the previous scan (m)
        self._step_turn = 0.0  # odometry turn since the previous scan (rad)
        self._step_gyro = False  # ...measured by a gyro
        self._gyro_since_keyframe = False  # every step since the last keyframe was
        self._local: PointMap | None = None
        self._since_loop_try = 0
        self._since_optimization = 0  # keyframes added since the graph was last optimised
        self.odometry_calibration = OdometryCalibration()
        self._end_walls = EndWallRuler()
        self.doubtful_turns = 0  # doubtful matches not believed: turned away from the odometry
        # odometry edges, their raw steps and whether the gyro turned them: each optimisation
        # measures them again with the calibration learnt so far (calibrate_odometry; the
        # wheels' once wheel_travel_scale_error is met, in x, y only)
        self._odometry_edges: list[tuple[Edge, Pose, bool]] = []
        # the occupancy grid's scans in the order they came: (keyframe, -1 for its own scan
        # or the index into its map_scans)
        self._map_index: list[tuple[int, int]] = []
        self._last_map_offset: Pose = (0.0, 0.0, 0.0)  # the last map scan, from its keyframe

    # ------------------------------------------------------------------ per scan
    def add_scan(self, stamp: float, odom: Pose, scan: Scan, gyro: bool = False) -> StepResult:
        """Track one scan taken at the odometry pose ``odom``; ``gyro``: the odometry's turn
        since the previous scan is a gyro's (:mod:`~sage_robot.nav.slam.gyro`)."""
        cfg = self.config
        if cfg.calibrate_odometry and cfg.end_wall_ruler:  # a straight stretch needs the gyro
            for fit in self._end_walls.step(odom, scan) if gyro else self._end_walls.end():
                self.odometry_calibration.add_ruler(fit.scale, fit.span_m)
        q = voxel_filter(self._scan_points(scan), cfg.scan_voxel_m)
        if self._last_odom is None and self.keyframes:  # a resumed session: start at its last keyframe
            self._last_odom = odom
        if self._last_odom is None:
            self._last_odom = odom
            self._add_keyframe(stamp, odom, scan, self.initial_pose, None)
            self.trajectory.append(_TrajectoryEntry(stamp, 0, (0.0, 0.0, 0.0)))
            return StepResult(self.pose, 1.0, 1.0, True, False)
        step = self._odometry_step(self._last_odom, odom)
        odometry = compose(self.pose, step)
        self._last_odom = odom
        self._step_dist = math.hypot(step[0], step[1])
        self._step_turn = abs(step[2])
        self._step_gyro = gyro
        self._gyro_since_keyframe &= gyro
        match = self._match(q, step, odometry, (scan.laser[0], scan.laser[1]), gyro)
        if match is None or match.inliers < cfg.min_track_inliers:
            # dead-reckoned by the odometry: a glitch guess is only as good as its match
            pose, score, inliers = odometry, 0.0, match.inliers if match else 0.0
            self.odometry_calibration.observe(pose, odom, None)
        else:
            pose, score, inliers = match.pose, match.score, match.inliers
            self.odometry_calibration.observe(pose, odom, match.information)
        self._last_step = relative(self.pose, pose)
        self.pose, self.last_score = pose, score
        kf = len(self.keyframes) - 1
        last = self.graph.poses[kf]
        moved = relative(last, pose)
        if math.hypot(moved[0], moved[1]) < cfg.keyframe_dist_m and abs(moved[2]) < cfg.keyframe_angle_rad:
            self.trajectory.append(_TrajectoryEntry(stamp, kf, moved))
            if score > 0:
                self._add_map_scan(kf, moved, scan)
            return StepResult(pose, score, inliers, False, False)
        info = match.information if match is not None and score > 0 else None
        self._add_keyframe(stamp, odom, scan, pose, info)
        self.trajectory.append(_TrajectoryEntry(stamp, len(self.keyframes) - 1, (0.0, 0.0, 0.0)))
        self._since_optimization += 1
        closed = self._try_loop_closure()
        return StepResult(self.pose, score, inliers, True, closed)

    def _match(
        self, q: np.ndarray, step: Pose, odometry: Pose, view: tuple[float, float], gyro: bool
    ) -> Match | None:
        """The scan's match from the odometry's prediction ``odometry``, or from a glitch guess
        when that one is doubtful; None for a doubtful match turned away from the odometry."""
        match = self._track(q, odometry, view)
        if self._doubtful(step, match):
            # Odometry glitches (frozen, then a jump) happen: also try "as the last step" and
            # "no motion", and keep the prediction whose match fits best. The wheels glitch,
            # not the gyro: a step it turned keeps its turn in both guesses.
            last, still = self._last_step, (0.0, 0.0, 0.0)
            if gyro:
                last, still = (last[0], last[1], step[2]), (0.0, 0.0, step[2])
            for guess in (compose(self.pose, last), compose(self.pose, still)):
                other = self._track(q, guess, view)
                if other is not None and (match is None or other.inliers > match.inliers + GLITCH_MARGIN):
                    match = other
        if match is not None and self._turned_away(match, odometry):
            self.doubtful_turns += 1
            return None
        return match

    def _wheel_travel_known(self) -> bool:
        """Is the calibration's scale known well enough for the wheels' travel to be stiff?"""
        return self.odometry_calibration.scale_error <= self.config.wheel_travel_scale_error

    def _turned_away(self, match: Match, odometry: Pose) -> bool:
        """Is this a doubtful match turned further from the odometry's prediction than
        ``doubtful_turn_gate_rad``?"""
        gate = self.config.doubtful_turn_gate_rad
        if gate <= 0 or match.inliers >= DOUBTFUL_INLIERS:
            return False
        return abs(math.remainder(match.pose[2] - odometry[2], 2 * math.pi)) > gate

    def _add_map_scan(self, kf: int, offset: Pose, scan: Scan) -> None:
        """Keep this tracked scan for the occupancy grid when it is far enough from the last."""
        cfg = self.config
        if cfg.map_scan_dist_m <= 0:
            return
        since = relative(self._last_map_offset, offset)
        if math.hypot(since[0], since[1]) >= cfg.map_scan_dist_m or abs(since[2]) >= cfg.map_scan_angle_rad:
            self._map_index.append((kf, len(self.keyframes[kf].map_scans)))
            self.keyframes[kf].map_scans.append((offset, scan))
            self._last_map_offset = offset

    def _scan_points(self, scan: Scan) -> np.ndarray:
        """Robot-frame end points of the returns used for matching (small foreground left out)."""
        cfg = self.config
        if cfg.drop_small_objects_m <= 0:
            return scan.points(cfg.max_range_m)
        mask = scan.hits(cfg.max_range_m)
        mask &= ~small_foreground(scan.ranges, scan.angles, mask, cfg.drop_small_objects_m)
        r, a = scan.ranges[mask].astype(np.float64), scan.angles[mask]
        lx, ly, lt = scan.laser
        return np.column_stack((lx + r * np.cos(a + lt), ly + r * np.sin(a + lt)))

    def _odometry_step(self, a: Pose, b: Pose) -> Pose:
        """The odometry's motion from ``a`` to ``b``, calibrated when that is on."""
        step = relative(a, b)
        return self.odometry_calibration.correct(step) if self.config.calibrate_odometry else step

    def _heading_sigma(self, gyro: bool, turn: float, wheels: float) -> float:
        """Noise (rad, 1 sigma) of the odometry's heading over a step that turned ``turn``
        (rad): a gyro's, else ``wheels``."""
        cfg = self.config
        return cfg.gyro_sigma_theta_rad + cfg.gyro_sigma_turn_fraction * turn if gyro else wheels

    def _doubtful(self, step: Pose, match: Match | None) -> bool:
        """Is the odometry step or its match suspicious?"""
        cfg = self.config
        if self._local is None:
            return False
        big = math.hypot(step[0], step[1]) > cfg.search_xy_m or abs(step[2]) > 0.5 * cfg.search_theta_rad
        return big or match is None or match.inliers < DOUBTFUL_INLIERS

    def _track(self, q: np.ndarray, predicted: Pose, view: tuple[float, float]) -> Match | None:
        cfg = self.config
        if self._local is None or len(q) < MIN_SCAN_POINTS:
            return None
        sxy = cfg.prior_sigma_xy_m + cfg.prior_sigma_xy_fraction * self._step_dist
        sth = self._heading_sigma(self._step_gyro, self._step_turn, cfg.prior_sigma_theta_rad)
        init, _ = self._local.search(
            q,
            predicted,
            cfg.search_xy_m,
            cfg.search_theta_rad,
            cfg.search_theta_step_rad,
            prior_sigma=(SEARCH_PRIOR_SCALE * sxy, SEARCH_PRIOR_SCALE * sth),
        )
        prior_info = np.diag([sxy**-2, sxy**-2, sth**-2])
        return self._local.refine(q, init, predicted, prior_info, view)

    # ------------------------------------------------------------------ keyframes
    def _add_keyframe(
        self, stamp: float, odom: Pose, scan: Scan, pose: Pose, info: np.ndarray | None
    ) -> None:
        cfg = self.config
        pts = voxel_filter(self._scan_points(scan), cfg.map_voxel_m)
        travel = 0.0
        if self.keyframes:
            prev = self.keyframes[-1]
            step = relative(prev.odom, odom)
            travel = prev.travel_m + math.hypot(step[0], step[1])
        node = self.graph.add_node(pose)
        self.keyframes.append(Keyframe(stamp, odom, scan, pts, travel))
        self._map_index.append((node, -1))
        self._last_map_offset = (0.0, 0.0, 0.0)
        if node > 0:
            i = node - 1
            z = relative(self.graph.poses[i], pose)
            if info is not None:
                backs = [b for b in cfg.submap_edge_strides if b < min(node, cfg.local_keyframes)]
                share = info / (1 + len(backs))  # one match: its information split over its edges
                # The match's information is about the map-frame x, y; the graph measures an
                # edge's error in the frame of its second pose. Turned into that frame (here and
                # for loop edges) it measured worse: docs/slam.md, "The matches' information".
                self.graph.add_edge(i, node, z, share, KIND_SCAN)
                for back in backs:  # scan-to-submap: stiffen the chain
                    a = node - 1 - back
                    za = relative(self.graph.poses[a], pose)
                    self.graph.add_edge(a, node, za, _across_travel(share, za), KIND_SCAN)
            odo = self._odometry_step(self.keyframes[i].odom, odom)
            dist = math.hypot(odo[0], odo[1])
            sxy = cfg.odom_sigma_xy_m + cfg.odom_sigma_fraction * dist
            gyro = self._gyro_since_keyframe
            wheels = cfg.calibrate_odometry and cfg.wheel_travel_scale_error > 0 and not gyro
            slipped = False
            if gyro or wheels:
                stiff = cfg.gyro_odom_sigma_xy_m + cfg.gyro_odom_sigma_xy_fraction * dist
                if info is None or math.hypot(odo[0] - z[0], odo[1] - z[1]) <= SLIP_SIGMAS * stiff:
                    if gyro or self._wheel_travel_known():
                        sxy = stiff
                    elif wheels:  # stiffer as the scale becomes known (weak while unknown: inf)
                        graded = stiff * self.odometry_calibration.scale_error / cfg.wheel_travel_scale_error
                        sxy = min(sxy, graded)
                else:
                    self.odometry_slips += 1
                    slipped = True
            sth = self._heading_sigma(
                gyro, abs(odo[2]), cfg.odom_sigma_theta_rad + cfg.odom_sigma_fraction * abs(odo[2])
            )
            self.graph.add_edge(i, node, odo, np.diag([sxy**-2, sxy**-2, sth**-2]), KIND_ODOM)
            if cfg.calibrate_odometry and (gyro or (wheels and not slipped)):  # measured again
                raw = relative(self.keyframes[i].odom, odom)
                self._odometry_edges.append((self.graph.edges[-1], raw, gyro))
        self._gyro_since_keyframe = True
        self._rebuild_local()

    def _points_of(self, indices: range | list[int]) -> tuple[np.ndarray, np.ndarray]:
        """Map-frame points and normals of these keyframes, one per map_voxel_m cell."""
        if not indices:
            return np.zeros((0, 2)), np.zeros((0, 2))
        pts = np.concatenate([transform(self.graph.poses[k], self.keyframes[k].points) for k in indices])
        nrm = np.concatenate(
            [rotate(self.graph.poses[k][2], self.keyframes[k].point_normals()) for k in indices]
        )
        need = self.config.map_min_support
        if need > 1 and len(indices) >= need:
            owner = np.repeat(np.arange(len(indices)), [len(self.keyframes[k].points) for k in indices])
            seen = supported(pts, owner, self.config.map_support_cell_m, need)
            pts, nrm = pts[seen], nrm[seen]
        keep = voxel_indices(pts, self.config.map_voxel_m)
        return pts[keep], nrm[keep]

    def _rebuild_local(self) -> None:
        cfg = self.config
        n = len(self.keyframes)
        pts, nrm = self._points_of(range(max(0, n - cfg.local_keyframes), n))
        if len(pts) < MIN_SCAN_POINTS:
            self._local = None
            return
        self._local = PointMap(pts, cfg.match, cfg.search_xy_m, nrm, oriented=cfg.oriented_normals)
        if cfg.map_normal_neighbours > 0:
            self._local.normals = smooth_normals(
                pts, self._local.tree, nrm, cfg.map_normal_neighbours, cfg.map_normal_radius_m
            )

    # ------------------------------------------------------------------ loop closure
    def _loop_candidate(self) -> int | None:
        cfg = self.config
        k = len(self.keyframes) - 1
        here = np.array(self.graph.poses[k][:2])
        travel = np.array([kf.travel_m for kf in self.keyframes[:k]])
        old = np.nonzero(travel < self.keyframes[k].travel_m - cfg.loop_min_travel_m)[0]
        if len(old) == 0:
            return None
        xy = np.array([self.graph.poses[j][:2] for j in old])
        dist = np.hypot(*(xy - here).T)
        best = int(np.argmin(dist))
        return int(old[best]) if dist[best] < cfg.loop_radius_m else None

    def _try_loop_closure(self) -> bool:
        cfg = self.config
        self._since_loop_try += 1
        if self._since_loop_try < cfg.loop_every_keyframes:
            return False
        j = self._loop_candidate()
        if j is None:
            return False
        self._since_loop_try = 0
        self.loop_attempts += 1
        k = len(self.keyframes) - 1
        h = cfg.loop_submap_keyframes
        limit = self.keyframes[k].travel_m - cfg.loop_min_travel_m
        members = [i for i in range(max(0, j - h), min(k, j + h + 1)) if self.keyframes[i].travel_m < limit]
        pts, nrm = self._points_of(members)
        if len(pts) < MIN_SCAN_POINTS:
            return False
        sub = PointMap(pts, cfg.match, cfg.loop_search_xy_m, nrm, oriented=cfg.oriented_normals)
        q = voxel_filter(self.keyframes[k].points, cfg.scan_voxel_m)
        if len(q) < MIN_SCAN_POINTS:  # a keyframe that saw (almost) nothing
            return False
        guess = self.graph.poses[k]
        init, score = sub.search(
            q,
            guess,
            cfg.loop_search_xy_m,
            cfg.loop_search_theta_rad,
            cfg.loop_search_theta_step_rad,
            distinct_m=cfg.loop_distinct_m,
        )
        if score < cfg.loop_min_score * 0.8 or sub.last_second_best > cfg.loop_max_ambiguity * score:
            return False
        laser = self.keyframes[k].scan.laser
        match = sub.refine(q, init, viewpoint=(laser[0], laser[1]))
        if match.score < cfg.loop_min_score or match.inliers < cfg.loop_min_inliers:
            return False
        z = relative(self.graph.poses[j], match.pose)
        backup = list(self.graph.poses)
        self._kf_pose_before = backup[k]
        self.graph.add_edge(j, k, z, match.information * cfg.loop_information_scale, KIND_LOOP)
        self._recalibrate_odometry_edges()
        self.graph.optimize()
        if self.graph.edge_errors()[-1] > cfg.loop_max_chi:  # the rest of the graph disagrees
            self.graph.edges.pop()
            self.graph.poses = backup
            self.loops_rejected += 1
            return False
        self._after_optimization()
        return True

    def optimize(self) -> dict[str, float]:
        """Optimise the pose graph and move the local map and current pose with it."""
        k = len(self.keyframes) - 1
        offset = relative(self.graph.poses[k], self.pose)
        self._recalibrate_odometry_edges()
        stats = self.graph.optimize()
        self._after_optimization(offset)
        return stats

    def _recalibrate_odometry_edges(self) -> None:
        """Measure the calibrated odometry edges again with the calibration learnt so far:
        the first metres were driven before it was known (2 % of scale is 16 cm over 8 m),
        and the estimate gets better as the drive goes on. A gyro's scale error and bias are
        the sensor's own, so its edges' heading is measured again too. The wheels' edges only
        once the scale is known (``wheel_travel_scale_error``), and in x, y only: they keep the
        heading of their time (measured again, wheels-only drives slid: docs/slam.md, "Odometry
        edges measured again"); measured again with a scale still 1 % off, a 25 m drive's
        map came out 0.4-0.9 % long."""
        cfg, known = self.config, self._wheel_travel_known()
        for edge, raw, gyro in self._odometry_edges:
            z = self.odometry_calibration.correct(raw)
            if gyro:
                edge.z = z
            elif known:  # the wheels' travel, stiff: x, y only
                edge.z = (z[0], z[1], edge.z[2])
                sxy = cfg.gyro_odom_sigma_xy_m + cfg.gyro_odom_sigma_xy_fraction * math.hypot(z[0], z[1])
                edge.information = np.diag([sxy**-2, sxy**-2, edge.information[2, 2]])

    @property
    def pending_keyframes(self) -> int:
        """Keyframes added since the graph was last optimised: only the tracker placed them."""
        return self._since_optimization

    def finish(self) -> None:
        """The drive is over (the map is saved): optimise the pending keyframes with the rest."""
        if self._since_optimization > 0 and len(self.keyframes) > 1:
            self.optimize()

    def _after_optimization(self, offset: Pose | None = None) -> None:
        k = len(self.keyframes) - 1
        if offset is None:
            offset = relative(self._kf_pose_before, self.pose)
        self.optimizations += 1
        self._since_optimization = 0
        self.map_version += 1
        before, self.pose = self.pose, compose(self.graph.poses[k], offset)
        self.odometry_calibration.moved(before, self.pose)
        self._rebuild_local()

    def resume(self) -> None:
        """After keyframes and graph were restored: track on from the last keyframe."""
        if self.keyframes:
            self.pose = self.graph.poses[-1]
            self._last_odom = None
            self.odometry_calibration.forget_anchors()
            self._end_walls = EndWallRuler()
            self._gyro_since_keyframe = False  # the new session's odometry starts here
            self._last_map_offset = (0.0, 0.0, 0.0)
            self._rebuild_local()

    # ------------------------------------------------------------------ results
    @property
    def loop_closures(self) -> int:
        return self.graph.loop_closures

    def keyframe_poses(self) -> list[Pose]:
        return list(self.graph.poses)

    @property
    def map_scan_count(self) -> int:
        """How many scans the occupancy grid is made of (keyframes' and map scans)."""
        return len(self._map_index)

    def map_scans(self, start: int = 0, poses: list[Pose] | None = None) -> tuple[list[Pose], list[Scan]]:
        """The occupancy grid's scans from the ``start``-th on, in the order they came, at their
        optimised poses (or following ``poses``, one per keyframe: the graph's moved elsewhere)."""
        base = self.graph.poses if poses is None else poses
        out_poses: list[Pose] = []
        out_scans: list[Scan] = []
        for k, e in self._map_index[start:]:
            kf = self.keyframes[k]
            if e < 0:
                out_poses.append(base[k])
                out_scans.append(kf.scan)
            else:
                offset, scan = kf.map_scans[e]
                out_poses.append(compose(base[k], offset))
                out_scans.append(scan)
        return out_poses, out_scans

    def restore_map_index(self) -> None:
        """After keyframes (and their map scans) were restored: each keyframe, then its scans."""
        self._map_index = [
            (k, e) for k, kf in enumerate(self.keyframes) for e in range(-1, len(kf.map_scans))
        ]

    def trajectory_array(self) -> tuple[np.ndarray, np.ndarray]:
        """(stamps (N,), poses (N, 3)) of every scan, following the optimised keyframes."""
        stamps = np.array([e.stamp for e in self.trajectory])
        poses = np.array([compose(self.graph.poses[e.keyframe], e.offset) for e in self.trajectory])
        return stamps, poses.reshape(-1, 3)
