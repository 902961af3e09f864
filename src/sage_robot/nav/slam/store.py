"""Save and load a SLAM session: the map for navigation plus everything needed to resume.

``save_session(slam, out_dir, name)`` writes, in ``out_dir``:

- ``NAME.yaml`` + ``NAME.pgm``: a map_server map (trinary, ``free_thresh: 0.1`` as the
  seed's robot sets by hand after SLAM Toolbox), readable by :func:`core.mapio.read_map`;
- ``NAME.graph.npz``: the pose graph (keyframe poses, edges with their information and kind)
  and each keyframe's stamp, odometry and scan, so :func:`load_session` rebuilds a
  :class:`Slam` that continues mapping where the session stopped;
- ``NAME.trajectory.txt``: ``stamp x y theta`` of every scan (s, m, m, rad).
"""

from __future__ import annotations

import json
import re
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from sage_robot.core.errors import ConfigError
from sage_robot.core.mapio import write_map
from sage_robot.core.msgs import OccupancyGrid
from sage_robot.nav.slam.engine import Keyframe, Slam, SlamConfig, _TrajectoryEntry
from sage_robot.nav.slam.matcher import MatchConfig
from sage_robot.nav.slam.occupancy import OccupancyMapper
from sage_robot.nav.slam.points import Pose, Scan, voxel_filter
from sage_robot.nav.slam.posegraph import Edge

NAV_FREE_THRESH = 0.1  # the seed's edit to every saved map
GRAPH_FORMAT = 1
NAME_RE = re.compile(r"^[A-Za-z0-9_.-]+$")


def check_name(name: str) -> str:
    if not NAME_RE.match(name) or name.startswith("."):
        raise ConfigError(f"map name {name!r}: use letters, digits, '_', '-' and '.' only")
    return name


def mapper_for(slam: Slam, resolution: float = 0.05) -> OccupancyMapper:
    """An empty occupancy mapper for this SLAM's lidar (its reach and range noise)."""
    return OccupancyMapper(resolution, slam.config.max_range_m, slam.config.match.range_noise_fraction)


def build_map(
    slam: Slam, resolution: float = 0.05, stamp: float = 0.0, poses: list[Pose] | None = None
) -> OccupancyGrid:
    """The occupancy grid of the SLAM's map scans at their optimised poses (or following
    ``poses``, one per keyframe: the optimised ones moved into another frame)."""
    mapper = mapper_for(slam, resolution)
    mapper.rebuild(*slam.map_scans(poses=poses))
    return mapper.to_grid(stamp)


def save_session(
    slam: Slam, out_dir: str | Path, name: str, grid: OccupancyGrid | None = None, resolution: float = 0.05
) -> dict[str, str]:
    """Write map, pose graph and trajectory; returns {"yaml", "pgm", "graph", "trajectory"} paths."""
    check_name(name)
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"cannot create {out}: {exc}") from None
    if not slam.keyframes:
        raise ConfigError("nothing to save: no scans were mapped yet")
    grid = grid if grid is not None else build_map(slam, resolution)
    yaml_path = write_map(grid, out / f"{name}.yaml", free_thresh=NAV_FREE_THRESH)
    graph_path = out / f"{name}.graph.npz"
    _save_graph(slam, graph_path)
    traj_path = out / f"{name}.trajectory.txt"
    stamps, poses = slam.trajectory_array()
    np.savetxt(traj_path, np.column_stack((stamps, poses)), fmt="%.6f", header="stamp x y theta (s m m rad)")
    return {
        "yaml": str(yaml_path),
        "pgm": str(yaml_path.with_suffix(".pgm")),
        "graph": str(graph_path),
        "trajectory": str(traj_path),
    }


def _save_graph(slam: Slam, path: Path) -> None:
    kfs, edges = slam.keyframes, slam.graph.edges
    extra = [(k, off, scan) for k, kf in enumerate(kfs) for off, scan in kf.map_scans]
    cfg = asdict(slam.config)
    arrays: dict[str, np.ndarray] = dict(
        format=np.array(GRAPH_FORMAT),
        config=np.array(json.dumps(cfg)),
        poses=slam.graph.as_array(),
        edge_ij=np.array([(e.i, e.j) for e in edges], dtype=np.int64).reshape(-1, 2),
        edge_z=np.array([e.z for e in edges], dtype=np.float64).reshape(-1, 3),
        edge_info=np.array([e.information for e in edges], dtype=np.float64).reshape(-1, 3, 3),
        edge_kind=np.array([e.kind for e in edges], dtype="U8"),
        kf_stamp=np.array([kf.stamp for kf in kfs]),
        kf_odom=np.array([kf.odom for kf in kfs], dtype=np.float64).reshape(-1, 3),
        kf_travel=np.array([kf.travel_m for kf in kfs]),
        **_scan_arrays("kf", [kf.scan for kf in kfs]),
        ms_keyframe=np.array([k for k, _, _ in extra], dtype=np.int64),
        ms_offset=np.array([off for _, off, _ in extra], dtype=np.float64).reshape(-1, 3),
        **_scan_arrays("ms", [scan for _, _, scan in extra]),
    )
    np.savez_compressed(path, allow_pickle=False, **arrays)


def _scan_arrays(prefix: str, scans: list[Scan]) -> dict[str, np.ndarray]:
    """Scans as flat arrays for ``np.savez``: ``PREFIX_lengths``, ``_ranges``, ``_angles``,
    ``_limits`` and ``_laser``."""
    limits = [(s.range_min, s.range_max) for s in scans]
    return {
        f"{prefix}_lengths": np.array([len(s.ranges) for s in scans], dtype=np.int64),
        f"{prefix}_ranges": np.concatenate([s.ranges for s in scans] or [np.zeros(0)]).astype(np.float32),
        f"{prefix}_angles": np.concatenate([s.angles for s in scans] or [np.zeros(0)]).astype(np.float32),
        f"{prefix}_limits": np.array(limits, dtype=np.float64).reshape(-1, 2),
        f"{prefix}_laser": np.array([s.laser for s in scans], dtype=np.float64).reshape(-1, 3),
    }


def _scans_from(data: Any, prefix: str) -> list[Scan]:
    """The scans :func:`_scan_arrays` wrote."""
    lengths = data[f"{prefix}_lengths"]
    if len(lengths) == 0:
        return []
    splits = np.cumsum(lengths)[:-1]
    ranges = np.split(data[f"{prefix}_ranges"], splits)
    angles = np.split(data[f"{prefix}_angles"].astype(np.float64), splits)
    limits, lasers = data[f"{prefix}_limits"], data[f"{prefix}_laser"]
    return [
        Scan(r, a, float(lim[0]), float(lim[1]), _pose(laser))
        for r, a, lim, laser in zip(ranges, angles, limits, lasers, strict=True)
    ]


def load_session(path: str | Path) -> Slam:
    """A :class:`Slam` restored from ``NAME.graph.npz`` (or the map's ``NAME.yaml`` beside it),
    ready to take more scans: tracking restarts at the last keyframe's pose."""
    path = Path(path)
    if path.suffix == ".yaml":
        path = path.with_name(path.stem + ".graph.npz")
    try:
        data = np.load(path, allow_pickle=False)
    except FileNotFoundError:
        raise ConfigError(f"{path}: pose graph file not found") from None
    except (OSError, ValueError) as exc:
        raise ConfigError(f"{path}: not a saved SLAM pose graph: {exc}") from None
    with data:
        if "format" not in data or int(data["format"]) != GRAPH_FORMAT:
            raise ConfigError(f"{path}: not a SAGE pose graph (format {GRAPH_FORMAT})")
        raw = json.loads(str(data["config"]))
        match: dict[str, Any] = {k: tuple(v) if isinstance(v, list) else v for k, v in raw["match"].items()}
        raw["match"] = MatchConfig(**match)
        slam = Slam(SlamConfig(**raw))
        poses = data["poses"]
        for p in poses:
            slam.graph.add_node((float(p[0]), float(p[1]), float(p[2])))
        for (i, j), z, info, kind in zip(
            data["edge_ij"], data["edge_z"], data["edge_info"], data["edge_kind"], strict=False
        ):
            slam.graph.edges.append(
                Edge(int(i), int(j), (float(z[0]), float(z[1]), float(z[2])), info, str(kind))
            )
        for k, scan in enumerate(_scans_from(data, "kf")):
            pts = voxel_filter(scan.points(slam.config.max_range_m), slam.config.map_voxel_m)
            odom = _pose(data["kf_odom"][k])
            slam.keyframes.append(
                Keyframe(
                    float(data["kf_stamp"][k]),
                    odom,
                    scan,
                    pts,
                    float(data["kf_travel"][k]),
                )
            )
            slam.trajectory.append(_TrajectoryEntry(float(data["kf_stamp"][k]), k, (0.0, 0.0, 0.0)))
        if "ms_keyframe" in data:  # sessions saved before map scans have none
            extra = zip(data["ms_keyframe"], data["ms_offset"], _scans_from(data, "ms"), strict=True)
            for k, off, scan in extra:
                slam.keyframes[int(k)].map_scans.append((_pose(off), scan))
    slam.restore_map_index()
    slam.resume()
    return slam


def _pose(v: np.ndarray) -> tuple[float, float, float]:
    return (float(v[0]), float(v[1]), float(v[2]))
