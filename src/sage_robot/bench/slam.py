"""SLAM over a CARMEN log: relation error (Kümmerle et al. 2009) and speed vs the log's duration.

``sage bench slam --log LOG --relations REL --json``. Without ``--relations`` (e.g. a
SLAM-corrected log, whose poses are the reference) give ``--odom-noise`` to corrupt the
odometry and ``--self-reference``: the error is then measured against the log's own
(corrected) poses over relations between scans ``--pairs-gap`` apart.
Published anchors on MIT CSAIL (translational): scan matching 0.106 m, GMapping 0.049 m,
graph mapping 0.004 m.
"""

from __future__ import annotations

import argparse
from typing import Any

ROUNDED_SHARE = 0.9  # short relations on the grid for the reference to count as rounded


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--log", help="CARMEN log (.clf, .log, .gz)")
    p.add_argument(
        "--sim",
        action="store_true",
        help="instead: map the shipped building by a scripted drive and compare with the truth",
    )
    p.add_argument("--sim-length", type=float, help="with --sim: stop the drive after this many metres")
    p.add_argument("--map", help="with --sim: the map to drive through (default: the shipped building)")
    p.add_argument(
        "--route",
        choices=("corridor", "auto"),
        help="with --sim: corridor (shipped building only) or auto (a planned tour; default with --map)",
    )
    p.add_argument(
        "--imu",
        action="store_true",
        help="with --sim: the odometry turns with the robot's gyro (as `sage up --mode slam --imu`)",
    )
    p.add_argument("--relations", help="Kümmerle relations file for the log")
    p.add_argument("--limit", type=int, help="only the first N scans")
    p.add_argument(
        "--odom-noise",
        type=float,
        nargs=2,
        metavar=("FRAC", "ROT"),
        help="add Gaussian odometry noise: fraction of translation, rad per rad",
    )
    p.add_argument(
        "--self-reference",
        action="store_true",
        help="reference = the log's own (corrected) poses, relations between nearby scans",
    )
    p.add_argument("--pairs-gap", type=int, default=2, help="scan gap of self-reference relations")
    p.add_argument("--seed", type=int, default=0, help="odometry noise seed")
    p.add_argument(
        "--seeds",
        help="with --sim: drive these seeds (0-15, 0,3,7) and report each and their mean and spread",
    )
    p.add_argument("--jobs", type=int, default=1, help="with --seeds: drives at a time (one process each)")


def run(args: argparse.Namespace) -> dict[str, Any]:
    import platform

    import numpy as np

    from sage_robot.core.errors import ConfigError
    from sage_robot.core.geometry import relative
    from sage_robot.nav.slam.carmen import read_log
    from sage_robot.nav.slam.relations import Relation, read_relations, relation_error
    from sage_robot.nav.slam.replay import noisy_odometry, replay_log

    if args.seeds is not None and not args.sim:
        raise ConfigError("--seeds drives the simulated robot: give it with --sim")
    if args.sim and args.seeds is not None:
        from sage_robot.bench.slam_seeds import parse_seeds, run_seeds

        return run_seeds(parse_seeds(args.seeds), args.jobs, args.sim_length, args.map, args.route, args.imu)
    if args.sim:
        from sage_robot.bench.slam_sim import run_check

        return {
            "bench": "slam_sim",
            **run_check(args.sim_length, args.seed, args.map, args.route, gyro=args.imu),
        }
    if not args.log:
        raise ConfigError("give --log LOG (with --relations REL or --self-reference), or --sim")
    if not args.relations and not args.self_reference:
        raise ConfigError("give --relations REL, or --self-reference for a corrected log")
    log = read_log(args.log)
    result = replay_log(
        log, limit=args.limit, odom_noise=tuple(args.odom_noise) if args.odom_noise else None, seed=args.seed
    )
    stamps, poses = result.slam.trajectory_array()
    scans = result.log.scans
    odo_err = None
    if args.relations:
        rels = read_relations(args.relations)
        last = stamps[-1] + 1e-3
        rels = [r for r in rels if r.t1 <= last and r.t2 <= last]
    else:
        # The corrected logs print stamps with too few digits to tell scans apart: index them.
        stamps = np.arange(len(scans), dtype=np.float64)
        ref = [s.odom for s in log.scans[: len(scans)]]
        g = args.pairs_gap
        rels = [
            Relation(float(k), float(k + g), *relative(ref[k], ref[k + g])) for k in range(len(scans) - g)
        ]
        if args.odom_noise:
            odo_est = np.array(
                noisy_odometry(
                    [s.odom for s in scans], tuple(args.odom_noise), np.random.default_rng(args.seed)
                )
            )
            odo_err = relation_error(stamps, odo_est, rels)
    err = relation_error(stamps, poses, rels)
    odo = np.array([s.odom for s in scans])
    out: dict[str, Any] = {
        "bench": "slam",
        "log": str(args.log),
        "scans": len(scans),
        "keyframes": len(result.slam.keyframes),
        "loop_closures": result.slam.loop_closures,
        "log_duration_s": round(result.log.duration_s, 1),
        "processing_s": round(result.seconds, 2),
        "realtime_factor": round(result.realtime_factor, 2),
        "cpu_s": round(result.cpu_seconds, 2),
        "realtime_factor_cpu": round(result.realtime_factor_cpu, 2),
        **err.as_dict(),
        "cpu": platform.processor() or platform.machine(),
    }
    if args.relations and not args.odom_noise:
        odo_err = relation_error(stamps, odo, rels)
        out.update(_reference_check(stamps, poses, odo, rels))
    if odo_err is not None:
        out["odometry_trans_error_mean_m"] = round(odo_err.trans_mean_m, 4)
        out["odometry_rot_error_mean_deg"] = round(odo_err.rot_mean_deg, 3)
    return out


def _reference_check(stamps: Any, poses: Any, odo: Any, rels: list[Any]) -> dict[str, Any]:
    """Short relations: how the reference relates to the odometry, the rounding floor and the
    distance to each reference's rounding cell (:mod:`nav.slam.cells`); long (loop) relations,
    which are not rounded, on their own."""
    import numpy as np

    from sage_robot.nav.slam.cells import cell_score
    from sage_robot.nav.slam.refcheck import SHORT_GAP_SCANS, reference_quantization
    from sage_robot.nav.slam.relations import (
        error_parts,
        reference_array,
        relation_indices,
        relative_poses,
        summarize,
    )

    i, j = relation_indices(stamps, rels)
    ref, est, o = reference_array(rels), relative_poses(poses, i, j), relative_poses(odo, i, j)
    short = np.abs(j - i) <= SHORT_GAP_SCANS
    out: dict[str, Any] = reference_quantization(ref[short], o[short], est[short]).as_dict()
    out["short_rot_error_mean_deg"] = round(summarize(*error_parts(ref[short], est[short])).rot_mean_deg, 4)
    far = summarize(*error_parts(ref[~short], est[~short]))
    out.update(
        long_relations=far.count,
        long_trans_error_mean_m=round(far.trans_mean_m, 5),
        long_trans_error_median_m=round(far.trans_median_m, 5),
        long_rot_error_mean_deg=round(far.rot_mean_deg, 4),
    )
    if out["reference_on_grid"] >= ROUNDED_SHARE:
        cells = cell_score(ref[short], o[short], est[short], poses[i[short], 2], stamps[i[short]])
        out.update(cells.as_dict())
    return out
