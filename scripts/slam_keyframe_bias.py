"""The scan matcher's error per keyframe of a bench drive, against local maps at the true poses.

Issue #23: the maps of some drives come out stretched along one axis by up to half a percent,
and the tracker's chain of matches carries that stretch (docs/slam.md, "Where the last
centimetres go"). This script takes the keyframes of one bench drive (``sage bench slam
--sim``'s world and settings), builds each keyframe's local map from the keyframes before it
(or, ``--backward``, after it) *at their true poses*, matches the keyframe's scan against it
from the true pose with the tracker's own matcher, and prints JSON:

- ``along_bias_mm`` / ``along_sd_mm``: the mean and spread of the match's error along the
  direction of travel (a bias the chain adds up keyframe by keyframe; ``drift_pct``: that
  bias over the distance between keyframes);
- ``by_range`` / ``by_side``: the split of the mean along-travel error into the scan points
  that cause it (one Gauss-Newton step from the true pose with the match's pairings:
  ``-uᵀ H⁻¹ Jᵢᵀ wᵢ rᵢ / σ²`` per point, H with the prior), by the point's range and by its
  offset across the travel (m); ``linear_sum_mm`` is their total, which should come close to
  ``along_bias_mm``.

``--rerender NOISE`` casts the keyframes' scans again in the drive's world without its people,
with this range noise (fraction of the range; 0: exact ranges), for the scans to match and the
maps alike: what the geometry alone does. ``--equal-weights``: every pairing weighs the same.

    python scripts/slam_keyframe_bias.py [--map M.yaml] [--seed N] [--length 80] [--backward]
        [--rerender 0.0] [--equal-weights] [--prior-sigma 0.02] [--heading-sigma 0.002]
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
from typing import Any

import numpy as np

from sage_robot.bench.slam_sim import map_drive
from sage_robot.bench.slam_world import SCAN_PERIOD_S
from sage_robot.core.errors import SageError
from sage_robot.core.geometry import relative
from sage_robot.nav.slam.engine import MIN_SCAN_POINTS, Keyframe, Slam
from sage_robot.nav.slam.matcher import Match, PointMap, smooth_normals
from sage_robot.nav.slam.points import Pose, Scan, transform, voxel_filter

MIN_STEP_M = 0.05  # keyframes closer than this to the previous one have no direction of travel
RANGE_BANDS_M = (0.0, 1.0, 2.0, 3.0, 5.0, 8.0, 13.0)
SIDE_BANDS_M = (0.0, 0.6, 1.0, 1.5, 3.0, 13.0)  # |offset across the travel| of a scan point
HEADING_PRIOR_SIGMA_RAD = 0.002  # the tracker's for a gyro-turned step


def rerender(drive: Any, stamps: list[float], noise: float, seed: int) -> list[Scan]:
    """The keyframes' scans cast again in the drive's world (clutter, no people)."""
    from sage_robot.sim.lidar import Lidar, LidarSpec

    world = drive.world
    spec = LidarSpec(
        noise_fraction=noise,
        noise_floor_m=world.spec.noise_floor_m if noise > 0 else 0.0,
        dropout_probability=0.0,
    )
    lidar = Lidar(spec, world.caster, np.random.default_rng(seed))
    laser = (spec.mount_x_m, spec.mount_y_m, spec.mount_yaw_rad)
    none = np.zeros((0, 2)), np.zeros((0, 6))
    return [
        Scan(
            lidar.measure(lidar.true_ranges(drive.truth[round(t / SCAN_PERIOD_S)], *none)),
            spec.angles(),
            spec.range_min_m,
            spec.range_max_m,
            laser,
        )
        for t in stamps
    ]


def local_map(slam: Slam, indices: range, equal_weights: bool) -> PointMap | None:
    cfg = slam.config
    pts, nrm = slam._points_of(indices)
    if len(pts) < MIN_SCAN_POINTS:
        return None
    pm = PointMap(pts, cfg.match, cfg.search_xy_m, nrm, oriented=cfg.oriented_normals)
    if cfg.map_normal_neighbours > 0:
        pm.normals = smooth_normals(pts, pm.tree, nrm, cfg.map_normal_neighbours, cfg.map_normal_radius_m)
    if equal_weights:  # the gates still widen with the range; every pairing weighs 1
        gates = pm._gates
        pm._gates = lambda q, v, g, equal=False: (gates(q, v, g)[0], np.ones(len(q)))  # type: ignore[method-assign]
    return pm


def contributions(
    pm: PointMap,
    q: np.ndarray,
    match: Match,
    true: Pose,
    view: tuple[float, float],
    u: np.ndarray,
    prior_info: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per paired scan point (paired and weighed as in the ``match``): its share of the
    along-travel error (m) of a Gauss-Newton step from the true pose, its range and its offset
    across."""
    cfg = pm.config
    _, ok, j, w = pm._associate(np.array(match.pose), q, view, cfg.icp_stages_m[-1], match.equal_weights)
    c, s = math.cos(true[2]), math.sin(true[2])
    qk, n = q[ok], pm.normals[j[ok]]
    r = np.einsum("ij,ij->i", n, transform(true, qk) - pm.points[j[ok]])
    jac = np.column_stack(
        (n[:, 0], n[:, 1], n[:, 0] * (-s * qk[:, 0] - c * qk[:, 1]) + n[:, 1] * (c * qk[:, 0] - s * qk[:, 1]))
    )
    wk = w[ok] * np.minimum(1.0, cfg.huber_m / np.sqrt(w[ok]) / np.maximum(np.abs(r), 1e-12))  # as refine()
    inv_var = cfg.point_sigma_m**-2
    a = np.linalg.solve(jac.T @ (jac * wk[:, None]) * inv_var + prior_info, np.array([u[0], u[1], 0.0]))
    share = -(jac @ a) * wk * r * inv_var
    rng = np.hypot(qk[:, 0] - view[0], qk[:, 1] - view[1])
    sensor = transform(true, np.array([view]))[0]
    across = (transform(true, qk) - sensor) @ np.array([-u[1], u[0]])
    return share, rng, across


def banded(share: np.ndarray, key: np.ndarray, bands: tuple[float, ...], count: int) -> dict[str, float]:
    return {
        f"{lo:g}-{hi:g}": round(1000 * float(share[(key >= lo) & (key < hi)].sum()) / count, 3)
        for lo, hi in itertools.pairwise(bands)
    }


def measure(args: argparse.Namespace) -> dict[str, Any]:
    drive = map_drive(args.length, args.seed, args.map, gyro=True)
    slam0 = drive.slam
    stamps = [kf.stamp for kf in slam0.keyframes]
    truth = [drive.truth[round(t / SCAN_PERIOD_S)] for t in stamps]
    scans = [kf.scan for kf in slam0.keyframes]
    map_scans = scans
    if args.rerender is not None:
        scans = rerender(drive, stamps, args.rerender, args.seed + 1)
        map_scans = rerender(drive, stamps, args.rerender, args.seed + 2)
    slam = Slam(slam0.config)
    cfg = slam.config
    slam.keyframes = [
        Keyframe(t, (0.0, 0.0, 0.0), s, voxel_filter(slam._scan_points(s), cfg.map_voxel_m), 0.0)
        for t, s in zip(stamps, map_scans, strict=True)
    ]
    slam.graph.poses = list(truth)
    n_local = cfg.local_keyframes
    prior_info = np.diag([args.prior_sigma**-2, args.prior_sigma**-2, args.heading_sigma**-2])
    along, steps, shares, ranges, acrosses = [], [], [], [], []
    equal = 0  # matches refined with equal weights (MatchConfig.equal_weights_isotropy)
    for k in range(n_local, len(truth) - (n_local if args.backward else 0)):
        step = relative(truth[k - 1], truth[k])
        dist = math.hypot(step[0], step[1])
        if dist < MIN_STEP_M:
            continue
        around = range(k + 1, k + 1 + n_local) if args.backward else range(k - n_local, k)
        pm = local_map(slam, around, args.equal_weights)
        q = voxel_filter(slam._scan_points(scans[k]), cfg.scan_voxel_m)
        if pm is None or len(q) < MIN_SCAN_POINTS:
            continue
        view = (scans[k].laser[0], scans[k].laser[1])
        match = pm.refine(q, truth[k], truth[k], prior_info, view)
        heading = math.atan2(truth[k][1] - truth[k - 1][1], truth[k][0] - truth[k - 1][0])
        u = np.array([math.cos(heading), math.sin(heading)])
        along.append(float((np.array(match.pose[:2]) - np.array(truth[k][:2])) @ u))
        equal += match.equal_weights
        steps.append(dist)
        share, rng, across = contributions(pm, q, match, truth[k], view, u, prior_info)
        shares.append(share)
        ranges.append(rng)
        acrosses.append(across)
    if not along:
        raise SageError("no keyframe to measure: drive longer (--length)")
    err = np.array(along)
    share_all, rng_all, across_all = np.concatenate(shares), np.concatenate(ranges), np.concatenate(acrosses)
    return {
        "map": str(drive.path),
        "seed": args.seed,
        "keyframes": len(err),
        "backward": args.backward,
        "rerender_noise": args.rerender,
        "equal_weights": args.equal_weights,
        "equal_weight_matches": equal,
        "along_bias_mm": round(1000 * float(err.mean()), 3),
        "along_sd_mm": round(1000 * float(err.std()), 2),
        "drift_pct": round(100 * float(err.sum() / np.sum(steps)), 3),
        "linear_sum_mm": round(1000 * float(share_all.sum()) / len(err), 3),
        "by_range": banded(share_all, rng_all, RANGE_BANDS_M, len(err)),
        "by_side": banded(share_all, np.abs(across_all), SIDE_BANDS_M, len(err)),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--map", default=None, help="a map YAML (default: the shipped building)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--length", type=float, default=80.0, help="metres of the drive to use")
    parser.add_argument("--backward", action="store_true", help="maps from the keyframes after")
    parser.add_argument(
        "--rerender",
        type=float,
        default=None,
        metavar="NOISE",
        help="cast the scans again without people, with this range-noise fraction",
    )
    parser.add_argument("--equal-weights", action="store_true")
    parser.add_argument("--prior-sigma", type=float, default=0.02, help="m, at the true pose")
    parser.add_argument(
        "--heading-sigma", type=float, default=HEADING_PRIOR_SIGMA_RAD, help="rad, at the true pose"
    )
    args = parser.parse_args(argv)
    try:
        print(json.dumps(measure(args), indent=1))
    except SageError as exc:
        print(f"slam_keyframe_bias: error: {exc}")
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
