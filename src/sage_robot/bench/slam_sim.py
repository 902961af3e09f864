"""SLAM simulation check: map the default building by a scripted drive and compare with the truth.

The drive follows the corridors of the shipped building (``data/maps/campus``): east along
the east-west corridor, back to the junction, north and then south along the north-south
corridor, turning on the spot at the ends. Scans are ray-cast on the true map (360 beams,
12 m, 1 cm noise) and the odometry drifts (2 % scale, ``YAW_DRIFT_RAD_PER_M``). The saved
map is compared with the true one:

- ``occupied_precision``: SLAM-occupied cells within ``MATCH_TOL_M`` of a true wall;
- ``occupied_recall``: true wall cells the robot saw (next to a SLAM-known cell) that have a
  SLAM-occupied cell within ``MATCH_TOL_M``;
- the trajectory error (m) against the true poses;
- navigation on the saved map: a path planned by ``nav.planner`` from the start to the end of
  the drive on the saved map (read back with ``free_thresh 0.1``) keeps ``NAV_CLEARANCE_M``
  from the true walls.
"""

from __future__ import annotations

import itertools
import math
import tempfile
from typing import Any

import numpy as np

Pose = tuple[float, float, float]

STEP_M = 0.3  # travel between scans
TURN_STEP_RAD = 0.4  # on-the-spot turning between scans
BEAMS = 360
RANGE_MAX_M = 12.0
RANGE_NOISE_M = 0.01
YAW_DRIFT_RAD_PER_M = 0.01
MATCH_TOL_M = 0.1
NAV_CLEARANCE_M = 0.15  # a planned path point this close to a true wall is a failure
ROBOT_INSCRIBED_M, INFLATION_M, COST_SCALING = 0.25, 0.55, 3.0


def corridor_route() -> list[tuple[float, float]]:
    """Waypoints (m) of the drive through the shipped building's corridors."""
    from sage_robot.sim.building import CORRIDOR_END_M, EW_Y, NS_X, SIZE_M

    ew, ns = sum(EW_Y) / 2, sum(NS_X) / 2
    west, east = CORRIDOR_END_M + 4.0, SIZE_M[0] - CORRIDOR_END_M - 4.0
    south, north = CORRIDOR_END_M + 4.0, SIZE_M[1] - CORRIDOR_END_M - 4.0
    return [(west, ew), (east, ew), (ns, ew), (ns, north), (ns, south)]


def drive_poses(route: list[tuple[float, float]], max_length_m: float | None = None) -> list[Pose]:
    poses: list[Pose] = []
    heading = math.atan2(route[1][1] - route[0][1], route[1][0] - route[0][0])
    travelled = 0.0
    for (x0, y0), (x1, y1) in itertools.pairwise(route):
        target = math.atan2(y1 - y0, x1 - x0)
        turn = math.remainder(target - heading, 2 * math.pi)
        for k in range(1, int(abs(turn) / TURN_STEP_RAD) + 1):
            poses.append((x0, y0, heading + math.copysign(k * TURN_STEP_RAD, turn)))
        heading = target
        length = math.hypot(x1 - x0, y1 - y0)
        for k in range(int(length / STEP_M)):
            if max_length_m is not None and travelled > max_length_m:
                return poses
            t = k * STEP_M / length
            poses.append((x0 + t * (x1 - x0), y0 + t * (y1 - y0), heading))
            travelled += STEP_M
    return poses


def run_check(max_length_m: float | None = None, seed: int = 0) -> dict[str, Any]:
    from sage_robot.core.geometry import compose, relative
    from sage_robot.core.mapio import read_map, world_to_cell
    from sage_robot.core.paths import package_data
    from sage_robot.nav.slam.engine import Slam
    from sage_robot.nav.slam.points import Scan
    from sage_robot.nav.slam.store import save_session
    from sage_robot.sim.raycast import GridRaycaster

    rng = np.random.default_rng(seed)
    truth_grid = read_map(package_data("maps", "campus", "map.yaml"))
    caster = GridRaycaster(truth_grid)
    truth = drive_poses(corridor_route(), max_length_m)
    angles = -math.pi + 2 * math.pi * np.arange(BEAMS) / BEAMS
    slam = Slam(initial_pose=truth[0])
    odom: Pose = truth[0]
    import time

    t0 = time.perf_counter()
    for k, pose in enumerate(truth):
        if k:
            dx, dy, dth = relative(truth[k - 1], pose)
            dist = math.hypot(dx, dy)
            step = (
                dx * (1 + rng.normal(0, 0.02)),
                dy + rng.normal(0, 0.005),
                dth * 1.02 + YAW_DRIFT_RAD_PER_M * dist + rng.normal(0, 0.003),
            )
            odom = compose(odom, step)
        ranges = caster.cast(pose[0], pose[1], angles + pose[2], RANGE_MAX_M) + rng.normal(
            0, RANGE_NOISE_M, BEAMS
        )
        slam.add_scan(k * 0.1, odom, Scan(ranges.astype(np.float32), angles, 0.1, RANGE_MAX_M))
    seconds = time.perf_counter() - t0
    _, est = slam.trajectory_array()
    err = np.hypot(est[:, 0] - np.array(truth)[:, 0], est[:, 1] - np.array(truth)[:, 1])
    odom_end = math.hypot(odom[0] - truth[-1][0], odom[1] - truth[-1][1])

    with tempfile.TemporaryDirectory() as tmp:
        paths = save_session(slam, tmp, "sim_check")
        saved = read_map(paths["yaml"])
    occupied = saved.data == 100
    rows, cols = np.nonzero(occupied)
    xs = saved.origin.x + (cols + 0.5) * saved.resolution
    ys = saved.origin.y + (rows + 0.5) * saved.resolution
    precision = float((caster.clearance(xs, ys) <= MATCH_TOL_M).mean()) if len(xs) else 0.0
    recall = _recall(truth_grid, saved, world_to_cell)
    nav = _navigate(saved, caster, truth[0], truth[-1])
    return {
        "scans": len(truth),
        "distance_m": round(STEP_M * sum(1 for a, b in itertools.pairwise(truth) if a[:2] != b[:2]), 1),
        "keyframes": len(slam.keyframes),
        "loop_closures": slam.loop_closures,
        "processing_s": round(seconds, 2),
        "trajectory_error_mean_m": round(float(err.mean()), 4),
        "trajectory_error_max_m": round(float(err.max()), 4),
        "odometry_end_error_m": round(odom_end, 3),
        "occupied_precision": round(precision, 4),
        "occupied_recall": round(recall, 4),
        **nav,
    }


def _recall(truth: Any, saved: Any, world_to_cell: Any) -> float:
    """Of the true wall cells next to space the SLAM map knows, those it marks as a wall."""
    from scipy.ndimage import binary_dilation, distance_transform_edt

    wall = truth.data >= 65
    rows, cols = np.nonzero(wall)
    xs = truth.origin.x + (cols + 0.5) * truth.resolution
    ys = truth.origin.y + (rows + 0.5) * truth.resolution
    r, c = world_to_cell(saved, xs, ys)
    inside = (r >= 0) & (r < saved.height) & (c >= 0) & (c < saved.width)
    free = saved.data == 0
    near_free = binary_dilation(free, iterations=2)
    seen = np.zeros(len(xs), dtype=bool)
    seen[inside] = near_free[r[inside], c[inside]]
    if not seen.any():
        return 0.0
    dist = distance_transform_edt(saved.data != 100) * saved.resolution
    return float((dist[r[seen], c[seen]] <= MATCH_TOL_M).mean())


def _navigate(saved: Any, caster: Any, start: Pose, goal: Pose) -> dict[str, Any]:
    """Plan on the saved map; check the path against the true walls."""
    try:
        from sage_robot.nav.costmap import Costmap
        from sage_robot.nav.planner import NoPath, plan
    except ImportError:  # the navigation extra is not installed
        return {"nav_planned": None}
    costmap = Costmap.from_grid(saved, ROBOT_INSCRIBED_M, INFLATION_M, COST_SCALING)
    try:
        path = plan(costmap, start[:2], goal[:2])
    except NoPath as exc:
        return {"nav_planned": False, "nav_error": str(exc)}
    clearance = caster.clearance(path.points[:, 0], path.points[:, 1])
    return {
        "nav_planned": True,
        "nav_path_m": round(path.length_m, 2),
        "nav_min_true_clearance_m": round(float(clearance.min()), 3),
        "nav_path_clear": bool(clearance.min() >= NAV_CLEARANCE_M),
    }
