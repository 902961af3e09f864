"""SLAM in simulation, on any map, against exact ground truth.

``sage bench slam --sim [--map M.yaml] [--route corridor|auto] [--sim-length M]`` drives the
simulated robot through a building map (default: the shipped one, ``data/maps/campus``) and
maps it with :class:`sage_robot.nav.slam.engine.Slam`:

- the drive: ``corridor`` (the shipped building only: east along the east-west corridor, back
  to the junction, north and then south along the north-south corridor) or ``auto`` (any map:
  a tour through well-spread free spots and back to the start, planned on the map;
  :mod:`sage_robot.bench.slam_route`), one scan every ``STEP_M`` of travel (0.5 m/s, a scan
  every 0.2 s) and ``TURN_STEP_RAD`` of turning on the spot;
- the world (:mod:`sage_robot.bench.slam_world`): the map with clutter, walking people, the
  robot's lidar model and drifting wheel odometry.

Scores, against the true poses and the true map (with its clutter):

- ``ate_rmse_m``: RMSE of the position error of every scan (m), in the map frame (the SLAM
  starts at the true first pose; no alignment);
- ``ate_aligned_rmse_m``: the same after the rigid motion that fits the estimate best (the
  absolute trajectory error as the TUM benchmark defines it), and ``travel_scale``: the
  scale a similarity alignment takes on top (above 1: the estimate reads the travel short;
  below 1: long), with ``ate_scale_aligned_rmse_m`` the error left after it
  (:mod:`sage_robot.nav.slam.trajectory`);
- ``return_error_m``: the position error at the end of the drive (back at the start for
  ``auto``: the map keeps its shape when the robot returns);
- map agreement (:mod:`sage_robot.nav.slam.mapscore`): mean distance from the mapped walls
  to the true walls, and the fraction of the true walls the lidar hit that are mapped, with
  the map put into the true frame by the trajectory's rigid alignment (``*_unaligned``: as
  mapped, from the true first pose);
- navigation on the map: a path planned by ``nav.planner`` on the SLAM map from the start to
  the drive's farthest point keeps ``NAV_CLEARANCE_M`` from the true walls.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from sage_robot.bench.slam_route import (
    COST_SCALING,
    INFLATION_M,
    ROBOT_INSCRIBED_M,
    Pose,
    auto_route,
    corridor_route,
    drive_poses,
)

STEP_M = 0.1  # travel between scans (0.5 m/s, a scan every 0.2 s)
TURN_STEP_RAD = 0.2  # on-the-spot turning between scans (1 rad/s)
MIN_SEEN_HITS = 3  # a true wall cell counts as seen after this many lidar returns in it
NAV_CLEARANCE_M = 0.15  # a planned path point this close to a true wall is a failure
ROUTES = ("corridor", "auto")


def shipped_map() -> Path:
    from sage_robot.core.paths import package_data

    return Path(package_data("maps", "campus", "map.yaml"))


def plan_drive(grid: Any, route: str, max_length_m: float | None) -> list[Pose]:
    """The true poses of the drive's scans."""
    from sage_robot.core.errors import ConfigError

    if route not in ROUTES:
        raise ConfigError(f"--route {route!r}: use one of {', '.join(ROUTES)}")
    waypoints = corridor_route() if route == "corridor" else auto_route(grid)
    poses = drive_poses(waypoints, STEP_M, TURN_STEP_RAD, max_length_m)
    if len(poses) < 2:
        raise ConfigError("the drive is too short to map anything: give a longer --sim-length or another map")
    return poses


def level_origin(grid: Any) -> Any:
    """``grid`` with its origin's yaw dropped: a map saved turned (``origin: [x, y, yaw]``) is
    simulated and mapped in its image's frame. The yaw only turns the whole building in the
    map frame, which changes nothing for a drive through it, and navigation's costmaps, the
    people's paths and the lidar's ray casting all work on maps whose rows run along x."""
    from sage_robot.core.msgs import Pose2D

    if grid.origin.theta == 0.0:
        return grid
    return dataclasses.replace(grid, origin=Pose2D(grid.origin.x, grid.origin.y, 0.0))


def slam_config(spec: Any) -> Any:
    """SLAM settings for the simulated lidar, as the robot's ``slam`` node makes them for its
    ``slam.range_noise_fraction`` (:func:`sage_robot.nav.slam.tuning.noisy_lidar_config`),
    with the lidar's reach."""
    from sage_robot.nav.slam.engine import SlamConfig
    from sage_robot.nav.slam.tuning import noisy_lidar_config

    return noisy_lidar_config(SlamConfig(max_range_m=spec.range_max_m), spec.noise_fraction)


@dataclass
class Drive:
    """A mapped drive: the SLAM that mapped it, the true poses of its scans and its world."""

    slam: Any  # sage_robot.nav.slam.engine.Slam
    truth: list[Pose]
    world: Any  # sage_robot.bench.slam_world.SimDrive
    path: Path
    route: str
    gyro: bool
    cpu_s: float


def map_drive(
    max_length_m: float | None = None,
    seed: int = 0,
    map_path: str | Path | None = None,
    route: str | None = None,
    people: bool = True,
    clutter: bool = True,
    gyro: bool = False,
    config: Any = None,
) -> Drive:
    """Drive the simulated robot through the map and map it (``config``: the SLAM settings,
    :func:`slam_config`'s by default); ``route`` defaults to ``corridor`` on the shipped map,
    else ``auto``; ``gyro``: the odometry turns with the robot's gyro."""
    from sage_robot.bench.slam_world import SCAN_PERIOD_S, SimDrive
    from sage_robot.core.errors import ConfigError
    from sage_robot.core.mapio import read_map
    from sage_robot.nav.slam.engine import Slam
    from sage_robot.nav.slam.gyro import GyroOdometry
    from sage_robot.nav.slam.points import Scan

    path = Path(map_path) if map_path is not None else shipped_map()
    if not path.is_file():
        raise ConfigError(f"--map {path}: no such map file")
    route = route or ("corridor" if map_path is None else "auto")
    if route == "corridor" and path.resolve() != shipped_map().resolve():
        raise ConfigError(
            "--route corridor drives the shipped building's corridors: use --route auto with --map"
        )
    truth_grid = level_origin(read_map(path))
    truth = plan_drive(truth_grid, route, max_length_m)
    world = SimDrive(truth_grid, truth, seed, people=people, clutter=clutter, gyro=gyro)
    sp = world.spec
    angles = sp.angles()
    slam = Slam(config if config is not None else slam_config(sp), initial_pose=truth[0])
    fuse = GyroOdometry()
    t0 = time.process_time()
    for k in range(len(truth)):
        wheels = world.odometry(k)
        odom, turned = fuse.step(wheels, (0, world.gyro_yaw) if gyro else None)
        ranges = world.ranges(k)
        scan = Scan(ranges, angles, sp.range_min_m, sp.range_max_m, world.laser)
        slam.add_scan(k * SCAN_PERIOD_S, odom, scan, gyro=turned)
    slam.finish()  # as the robot's slam node does when it saves the map
    return Drive(slam, truth, world, path, route, gyro, time.process_time() - t0)


def run_check(
    max_length_m: float | None = None,
    seed: int = 0,
    map_path: str | Path | None = None,
    route: str | None = None,
    people: bool = True,
    clutter: bool = True,
    gyro: bool = False,
) -> dict[str, Any]:
    """Drive, map and score (:func:`map_drive`; ``sage bench slam --sim [--imu]``)."""
    from sage_robot.bench.slam_world import SCAN_PERIOD_S
    from sage_robot.nav.slam.mapscore import score_map
    from sage_robot.nav.slam.store import build_map
    from sage_robot.nav.slam.trajectory import align

    drive = map_drive(max_length_m, seed, map_path, route, people, clutter, gyro)
    slam, truth, world, path, route = drive.slam, drive.truth, drive.world, drive.path, drive.route
    cpu_s = drive.cpu_s
    _, est = slam.trajectory_array()
    true_xy = np.asarray(truth)[:, :2]
    err = np.hypot(*(est[:, :2] - true_xy).T)
    moved = np.hypot(*np.diff(true_xy, axis=0).T)
    rigid, similar = align(est[:, :2], true_xy), align(est[:, :2], true_xy, with_scale=True)
    mapped = build_map(slam)
    seen = world.seen >= MIN_SEEN_HITS
    # The map is scored in the true frame after the trajectory's rigid alignment (a map is
    # defined up to where it is put; the unaligned score also counts the drift from the start).
    in_truth = build_map(slam, poses=[rigid.apply(p) for p in slam.keyframe_poses()])
    score = score_map(world.grid, in_truth, seen)
    unaligned = score_map(world.grid, mapped, seen)
    far = truth[int(np.argmax(np.hypot(*(true_xy - true_xy[0]).T)))]
    return {
        "map": str(path),
        "route": route,
        "gyro": gyro,
        "scans": len(truth),
        "distance_m": round(float(moved.sum()), 1),
        "duration_s": round(len(truth) * SCAN_PERIOD_S, 1),
        "people": len(world.crowd.people),
        "clutter": world.clutter,
        "keyframes": len(slam.keyframes),
        "loop_closures": slam.loop_closures,
        "odometry_slips": slam.odometry_slips,
        "doubtful_turns": slam.doubtful_turns,
        "cpu_s": round(cpu_s, 2),
        "ate_rmse_m": round(float(np.sqrt((err**2).mean())), 4),
        "ate_aligned_rmse_m": round(rigid.rmse_m, 4),
        "ate_scale_aligned_rmse_m": round(similar.rmse_m, 4),
        "travel_scale": round(similar.scale, 5),
        "trajectory_error_mean_m": round(float(err.mean()), 4),
        "trajectory_error_max_m": round(float(err.max()), 4),
        "return_error_m": round(float(err[-1]), 4),
        "odometry_end_error_m": round(math.dist(world.odom[:2], truth[-1][:2]), 3),
        **score.as_dict(),
        "occupied_recall": round(score.walls_found, 4),
        "wall_distance_mean_unaligned_m": round(unaligned.wall_distance_mean_m, 4),
        "walls_found_unaligned": round(unaligned.walls_found, 4),
        **_navigate(mapped, world.caster, truth[0], far),
    }


def _navigate(saved: Any, caster: Any, start: Pose, goal: Pose) -> dict[str, Any]:
    """Plan on the SLAM map; check the path against the true walls."""
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
