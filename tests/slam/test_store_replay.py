"""Save → load round trip, and a short replay of the real MIT CSAIL log."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import yaml

from sage_robot.core.errors import ConfigError
from sage_robot.core.geometry import relative
from sage_robot.core.mapio import read_map, world_to_cell
from sage_robot.nav.slam.engine import Keyframe, Slam
from sage_robot.nav.slam.occupancy import OccupancyMapper
from sage_robot.nav.slam.points import Pose, Scan, transform
from sage_robot.nav.slam.relations import read_relations, relation_error
from sage_robot.nav.slam.replay import replay_log
from sage_robot.nav.slam.store import build_map, load_session, save_session

from .synth import corridor_loop, loop_path, simulate

CSAIL = "slam/mit-csail/mit-csail.clf"
CSAIL_RELATIONS = "slam/mit-csail/mit-csail.relations"


def short_session(n: int = 40, step_m: float = 0.35) -> tuple[Slam, list[Pose], list[Scan]]:
    truth = loop_path(step_m=step_m)[:n]
    drive = simulate(corridor_loop(), truth, yaw_drift=0.01)
    slam = Slam(initial_pose=truth[0])
    for k in range(n):
        slam.add_scan(0.1 * k, drive.odom[k], drive.scans[k])
    return slam, drive.odom, drive.scans


def test_save_load_round_trip_and_resume(tmp_path: Path) -> None:
    slam, _odom, scans = short_session(step_m=0.1)
    paths = save_session(slam, tmp_path / "out", "floor1")
    assert set(paths) == {"yaml", "pgm", "graph", "trajectory"}
    meta = yaml.safe_load(Path(paths["yaml"]).read_text())
    assert meta["free_thresh"] == 0.1
    assert meta["image"] == "floor1.pgm"
    grid = read_map(paths["yaml"])
    built = build_map(slam)
    assert grid.data.shape == built.data.shape
    assert grid.resolution == built.resolution
    assert np.array_equal(grid.data == 100, built.data >= 65)
    assert np.array_equal(grid.data == 0, (built.data >= 0) & (built.data <= 25))
    traj = np.loadtxt(paths["trajectory"])
    assert traj.shape == (40, 4)

    back = load_session(paths["yaml"])
    assert back.graph.poses == slam.graph.poses
    assert [(e.i, e.j, e.kind) for e in back.graph.edges] == [(e.i, e.j, e.kind) for e in slam.graph.edges]
    for a, b in zip(back.graph.edges, slam.graph.edges, strict=True):
        np.testing.assert_allclose(a.information, b.information)
    for ka, kb in zip(back.keyframes, slam.keyframes, strict=True):
        np.testing.assert_array_equal(ka.scan.ranges, kb.scan.ranges)
        assert ka.odom == kb.odom
        assert ka.stamp == kb.stamp
    assert back.config == slam.config
    # The scans between keyframes that the grid is made of come back too, in their order.
    assert back.map_scan_count == slam.map_scan_count > len(slam.keyframes)
    (poses_a, scans_a), (poses_b, scans_b) = back.map_scans(), slam.map_scans()
    np.testing.assert_allclose(poses_a, poses_b)
    for sa, sb in zip(scans_a, scans_b, strict=True):
        np.testing.assert_array_equal(sa.ranges, sb.ranges)
    rebuilt = build_map(back).data  # angles are saved as float32: the drawn world puts many
    # beams exactly on cell borders, and a few of those fall the other way
    assert rebuilt.shape == built.data.shape
    assert (rebuilt == built.data).mean() > 0.99
    # Resume: the robot is where the session ended; a new scan there matches the old map.
    result = back.add_scan(99.0, (5.0, 5.0, 1.0), scans[-1])
    assert result.inliers > 0.9
    assert np.hypot(result.pose[0] - slam.pose[0], result.pose[1] - slam.pose[1]) < 0.05


def test_the_grid_is_made_of_keyframes_and_the_scans_between_them() -> None:
    slam, _, _ = short_session(step_m=0.1)
    poses, scans = slam.map_scans()
    assert len(poses) == slam.map_scan_count
    keyframe_scans = [kf.scan for kf in slam.keyframes]
    assert sum(any(s is k for k in keyframe_scans) for s in scans) == len(slam.keyframes)
    cfg = slam.config
    for k, kf in enumerate(slam.keyframes):
        last = (0.0, 0.0, 0.0)  # each map scan is far enough from the one before it
        for offset, _ in kf.map_scans:
            since = relative(last, offset)
            far = math.hypot(since[0], since[1]) >= cfg.map_scan_dist_m
            assert far or abs(since[2]) >= cfg.map_scan_angle_rad
            last = offset
        assert [p for p, s in zip(poses, scans, strict=True) if s is kf.scan] == [slam.graph.poses[k]]
    # Following other keyframe poses (the graph moved into another frame) moves them all.
    shifted = [(x + 1.0, y, th) for x, y, th in slam.keyframe_poses()]
    moved, _ = slam.map_scans(poses=shifted)
    np.testing.assert_allclose(np.array(moved)[:, 0], np.array(poses)[:, 0] + 1.0)
    # Keyframes only: as many grid scans as keyframes.
    few = Slam(dataclasses.replace(cfg, map_scan_dist_m=0.0), initial_pose=slam.initial_pose)
    _, odom, all_scans = short_session(step_m=0.1)
    for k, scan in enumerate(all_scans):
        few.add_scan(0.1 * k, odom[k], scan)
    assert few.map_scan_count == len(few.keyframes)


def test_bad_names_and_files(tmp_path: Path) -> None:
    slam, _, _ = short_session(3)
    with pytest.raises(ConfigError, match="use letters"):
        save_session(slam, tmp_path, "../evil")
    with pytest.raises(ConfigError, match="nothing to save"):
        save_session(Slam(), tmp_path, "empty")
    with pytest.raises(ConfigError, match="pose graph file not found"):
        load_session(tmp_path / "none.graph.npz")
    (tmp_path / "junk.graph.npz").write_bytes(b"not a zip")
    with pytest.raises(ConfigError, match="not a saved SLAM pose graph"):
        load_session(tmp_path / "junk.graph.npz")


def wall_agreement(poses: list[Pose], keyframes: list[Keyframe]) -> float:
    """Fraction of keyframe hits within one cell of a wall of the map built from ``poses``."""
    mapper = OccupancyMapper(0.05, 30.0)
    mapper.rebuild(poses, [kf.scan for kf in keyframes])
    grid = mapper.to_grid()
    occupied = grid.data >= 65
    near = occupied.copy()
    for axis in (0, 1):
        for shift in (-1, 1):
            near |= np.roll(occupied, shift, axis=axis)
    hits = []
    for pose, kf in zip(poses, keyframes, strict=True):
        pts = transform(pose, kf.points)
        rows, cols = world_to_cell(grid, pts[:, 0], pts[:, 1])
        hits.append(near[rows, cols])
    return float(np.concatenate(hits).mean())


def test_short_csail_replay_walls_match(shared_data: Callable[[str], Path]) -> None:
    """The first 100 real scans: the scans agree with the map's walls better than with
    odometry alone, and the relation error is below the odometry's."""
    result = replay_log(shared_data(CSAIL), limit=100)
    slam = result.slam
    odom = [kf.odom for kf in slam.keyframes]
    slam_fit, odom_fit = (
        wall_agreement(slam.keyframe_poses(), slam.keyframes),
        wall_agreement(odom, slam.keyframes),
    )
    assert slam_fit > 0.75
    assert slam_fit > odom_fit + 0.1
    stamps, poses = slam.trajectory_array()
    rels = [
        r for r in read_relations(shared_data(CSAIL_RELATIONS)) if r.t2 <= stamps[-1] and r.t1 <= stamps[-1]
    ]
    assert len(rels) > 20
    est = relation_error(stamps, poses, rels)
    odo = relation_error(stamps, np.array([s.odom for s in result.log.scans]), rels)
    assert est.trans_mean_m < 0.03
    assert est.rot_mean_deg < 0.5 * odo.rot_mean_deg
