"""Every pose-graph edge of a simulated SLAM drive against the truth, and oracle graphs.

Issue #23: the trajectory error of a drive is the pose graph's compromise between its edges, so
the way to find what limits it is to compare each edge with the true relative pose. This script
maps one bench drive (``sage bench slam --sim``'s world and settings) and prints JSON:

- ``edges``: per kind (``step``: the scan edge to the previous keyframe; ``submap``: scan edges
  further back; ``odom``; ``loop``), the error at the true poses in the frame the graph measures
  it in (``e = Z⁻¹ · Tᵢ⁻¹ · Tⱼ``), split along the edge's travel, across it and in heading (rms,
  mm and degrees), the sigma the edge's information claims in each (the conditional one,
  ``1 / √(uᵀ I u)``, median; ``null`` where it claims nothing), the mean along-travel error per
  quarter of the drive (a bias shows as a sign that holds), and ``chi2_per_dof``: the mean of
  ``eᵀ I e`` over the information's rank (about 1 when the information is right; above:
  the edges claim more than they hold);
- ``oracle`` (``--oracle``): the aligned trajectory error (m) after optimising the graph again
  with one kind's measurements (or one component of them) replaced by the true ones: what that
  error costs the drive;
- ``floor`` (``--floor``; also in ``--oracle``): the same with *every* scan edge (step,
  submap, loop) true and the odometry as measured, then also the odometry edges' remaining
  scale error taken out: what the odometry alone leaves;
- ``segments``: the error along the drive, per ``--segment`` keyframes (rms, mean offset, loop
  closures ending there).

    python scripts/slam_edge_diagnosis.py [--map M.yaml] [--seed N] [--imu] [--sim-length M]
        [--oracle] [--floor] [--segment 50] [--set '{"loop_information_scale": 1.0}']
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import json
import math
from collections.abc import Callable
from typing import Any

import numpy as np

from sage_robot.bench.slam_sim import map_drive, slam_config
from sage_robot.bench.slam_world import SCAN_PERIOD_S
from sage_robot.core.errors import SageError
from sage_robot.core.geometry import compose, relative
from sage_robot.nav.slam.engine import MIN_TRAVEL_M, Slam
from sage_robot.nav.slam.posegraph import KIND_LOOP, Edge, PoseGraph
from sage_robot.nav.slam.trajectory import align

Pose = tuple[float, float, float]
KINDS = ("step", "submap", "odom", "loop")
COMPONENTS = ("along", "across", "heading")
REOPTIMISE_ITERATIONS = 50
RANK_TOLERANCE = 1e-9  # of the information's largest entry: directions below it carry nothing


def kind_of(e: Edge) -> str:
    if e.kind == "scan":
        return "step" if e.j - e.i == 1 else "submap"
    return str(e.kind)


def travel_axis(z: Pose) -> np.ndarray:
    """Unit vector of the edge's travel in its error frame (x when it barely moves)."""
    dist = math.hypot(z[0], z[1])
    if dist < MIN_TRAVEL_M:
        return np.array([1.0, 0.0])
    c, s = math.cos(z[2]), math.sin(z[2])
    return np.array([c * z[0] + s * z[1], -s * z[0] + c * z[1]]) / dist


def error_at(z: Pose, true_z: Pose) -> np.ndarray:
    """The graph's error of an edge measuring ``z`` when the truth is ``true_z``."""
    e = np.array(relative(z, true_z))
    e[2] = math.remainder(e[2], 2 * math.pi)
    return e


def components(e: np.ndarray, u: np.ndarray) -> tuple[float, float, float]:
    return float(u @ e[:2]), float(-u[1] * e[0] + u[0] * e[1]), float(e[2])


def claimed_sigma(info: np.ndarray, direction: np.ndarray) -> float | None:
    w = float(direction @ info @ direction)
    return 1.0 / math.sqrt(w) if w > 1e-12 else None


def edge_table(slam: Slam, truth_kf: list[Pose]) -> dict[str, Any]:
    rows: dict[str, list[tuple[float, ...]]] = {k: [] for k in KINDS}
    chi: dict[str, list[float]] = {k: [] for k in KINDS}
    for e in slam.graph.edges:
        zt = relative(truth_kf[e.i], truth_kf[e.j])
        err = error_at(e.z, zt)
        u = travel_axis(e.z)
        along, across, heading = components(err, u)
        dirs = (np.array([u[0], u[1], 0.0]), np.array([-u[1], u[0], 0.0]), np.array([0.0, 0.0, 1.0]))
        sig = [claimed_sigma(e.information, d) for d in dirs]
        rows[kind_of(e)].append((along, across, heading, *(s if s is not None else math.nan for s in sig)))
        scale = max(float(np.abs(e.information).max()), 1e-30)
        rank = max(int(np.linalg.matrix_rank(e.information, tol=RANK_TOLERANCE * scale)), 1)
        chi[kind_of(e)].append(float(err @ e.information @ err) / rank)
    out: dict[str, Any] = {}
    for kind, r in rows.items():
        if not r:
            continue
        a = np.array(r)
        q = max(len(a) // 4, 1)

        def med(col: np.ndarray) -> float | None:
            ok = col[np.isfinite(col)]
            return round(float(np.median(ok)) * 1000, 1) if len(ok) else None

        hmed = med(a[:, 5])
        out[kind] = {
            "n": len(a),
            "rms_along_mm": round(float(np.sqrt((a[:, 0] ** 2).mean())) * 1000, 1),
            "rms_across_mm": round(float(np.sqrt((a[:, 1] ** 2).mean())) * 1000, 1),
            "rms_heading_deg": round(float(np.degrees(np.sqrt((a[:, 2] ** 2).mean()))), 3),
            "claimed_along_mm": med(a[:, 3]),
            "claimed_across_mm": med(a[:, 4]),
            "claimed_heading_deg": None if hmed is None else round(math.degrees(hmed / 1000), 3),
            "mean_along_per_quarter_mm": [
                round(float(a[i * q : (i + 1) * q, 0].mean()) * 1000, 2) for i in range(4)
            ],
            "chi2_per_dof": round(float(np.mean(chi[kind])), 2),
        }
    return out


def trajectory_error(slam: Slam, poses: list[Pose], truth: list[Pose]) -> float:
    est = np.array([compose(poses[t.keyframe], t.offset) for t in slam.trajectory])
    return round(float(align(est[:, :2], np.asarray(truth)[:, :2]).rmse_m), 4)


def with_true(part: str | None) -> Callable[[Edge, Pose], Pose]:
    """A measurement with its error (all of it, or one component) taken out."""

    def fix(e: Edge, zt: Pose) -> Pose:
        if part is None:
            return zt
        err = error_at(e.z, zt)
        u = travel_axis(e.z)
        along, across, heading = components(err, u)
        parts = {"along": along, "across": across, "heading": heading}
        parts[part] = 0.0
        al, ac = parts["along"], parts["across"]
        left = (float(u[0] * al - u[1] * ac), float(u[1] * al + u[0] * ac), parts["heading"])
        z: Pose = compose(zt, relative(left, (0.0, 0.0, 0.0)))  # relative(z, zt) == left
        return z

    return fix


def oracle(slam: Slam, truth_kf: list[Pose], truth: list[Pose]) -> dict[str, float]:
    def reoptimised(kind: str | None, part: str | None) -> float:
        g: PoseGraph = copy.deepcopy(slam.graph)
        fix = with_true(part)
        for e in g.edges:
            if kind is not None and kind_of(e) == kind:
                e.z = fix(e, relative(truth_kf[e.i], truth_kf[e.j]))
        g.optimize(iterations=REOPTIMISE_ITERATIONS)
        return trajectory_error(slam, g.poses, truth)

    out = {"as_is": reoptimised(None, None)}
    out.update(floor(slam, truth_kf, truth))
    turned = copy.deepcopy(slam.graph)
    for e in turned.edges:
        if e.kind != "odom":
            e.information = in_edge_frame(e.information, turned.poses[e.j][2])
    out["turned"] = reoptimised_graph(turned, slam, truth)
    chi = chi2_per_kind(turned, truth_kf)
    for e in turned.edges:
        e.information = e.information / chi[kind_of(e)]
    out["turned_weighed"] = reoptimised_graph(turned, slam, truth)
    as_is = copy.deepcopy(slam.graph)
    chi = chi2_per_kind(as_is, truth_kf)
    for e in as_is.edges:
        e.information = e.information / chi[kind_of(e)]
    out["weighed"] = reoptimised_graph(as_is, slam, truth)
    for kind in KINDS:
        out[f"{kind}_true"] = reoptimised(kind, None)
        for part in COMPONENTS:
            out[f"{kind}_true_{part}"] = reoptimised(kind, part)
    return out


def floor(slam: Slam, truth_kf: list[Pose], truth: list[Pose]) -> dict[str, float]:
    """The error the odometry alone leaves: every scan edge (step, submap, loop) measuring the
    true relative pose, the odometry edges as measured (``scans_true``) and, besides, the
    odometry's remaining scale error taken out (``scans_true_odom_scaled``: each odometry edge
    scaled by the truth's length over the whole drive / the edges' length)."""
    g: PoseGraph = copy.deepcopy(slam.graph)
    odo = [e for e in g.edges if e.kind == "odom"]
    for e in g.edges:
        if e.kind != "odom":
            e.z = relative(truth_kf[e.i], truth_kf[e.j])
    g.optimize(iterations=REOPTIMISE_ITERATIONS)
    out = {"scans_true": trajectory_error(slam, g.poses, truth)}
    true_len = sum(math.dist(truth_kf[e.i][:2], truth_kf[e.j][:2]) for e in odo)
    odo_len = sum(math.hypot(e.z[0], e.z[1]) for e in odo)
    k = true_len / max(odo_len, 1e-9)
    for e in odo:
        e.z = (e.z[0] * k, e.z[1] * k, e.z[2])
    g.optimize(iterations=REOPTIMISE_ITERATIONS)
    out["scans_true_odom_scaled"] = trajectory_error(slam, g.poses, truth)
    out["odom_scale_error_pct"] = round((1 / k - 1) * 100, 3)
    return out


def in_edge_frame(info: np.ndarray, heading: float) -> np.ndarray:
    """A match's information on the map-frame pose, turned into the frame the graph measures
    the edge's error in (the second pose's, at ``heading``)."""
    c, s = math.cos(heading), math.sin(heading)
    t = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    out: np.ndarray = t.T @ info @ t
    return out


def chi2_per_kind(g: PoseGraph, truth_kf: list[Pose]) -> dict[str, float]:
    sums: dict[str, list[float]] = {}
    for e in g.edges:
        err = error_at(e.z, relative(truth_kf[e.i], truth_kf[e.j]))
        scale = max(float(np.abs(e.information).max()), 1e-30)
        rank = max(int(np.linalg.matrix_rank(e.information, tol=RANK_TOLERANCE * scale)), 1)
        sums.setdefault(kind_of(e), []).append(float(err @ e.information @ err) / rank)
    return {k: max(float(np.mean(v)), 1e-9) for k, v in sums.items()}


def reoptimised_graph(g: PoseGraph, slam: Slam, truth: list[Pose]) -> float:
    g.optimize(iterations=REOPTIMISE_ITERATIONS)
    return trajectory_error(slam, g.poses, truth)


def segments(slam: Slam, truth_kf: list[Pose], size: int) -> list[dict[str, Any]]:
    est, tru = np.array(slam.graph.poses), np.array(truth_kf)
    fit = align(est[:, :2], tru[:, :2])
    put = np.array([fit.apply((float(p[0]), float(p[1]), float(p[2]))) for p in est])
    d = put[:, :2] - tru[:, :2]
    ends = [e.j for e in slam.graph.edges if e.kind == KIND_LOOP]
    out = []
    for b in range(0, len(d), size):
        s = d[b : b + size]
        out.append(
            {
                "keyframes": [b, b + len(s) - 1],
                "true_xy": [round(float(tru[b, 0]), 1), round(float(tru[b, 1]), 1)],
                "rms_m": round(float(np.sqrt((s**2).sum(axis=1).mean())), 3),
                "mean_dx_m": round(float(s[:, 0].mean()), 3),
                "mean_dy_m": round(float(s[:, 1].mean()), 3),
                "loops": sum(1 for j in ends if b <= j < b + size),
            }
        )
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--map", default=None, help="a map YAML (default: the shipped building)")
    ap.add_argument("--route", default=None, choices=("corridor", "auto"))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--imu", action="store_true", help="the odometry turns with the gyro")
    ap.add_argument("--sim-length", type=float, default=None, help="drive at most this far (m)")
    ap.add_argument("--oracle", action="store_true", help="optimise again with true measurements")
    ap.add_argument("--floor", action="store_true", help="only the oracle with every scan edge true")
    ap.add_argument("--segment", type=int, default=0, help="error per this many keyframes")
    ap.add_argument("--set", default="{}", help="SlamConfig fields to change (JSON; 'match': {...})")
    args = ap.parse_args()
    from sage_robot.sim.lidar import LidarSpec

    try:
        over = json.loads(args.set)
        base = slam_config(LidarSpec())
        match = dataclasses.replace(base.match, **over.pop("match", {}))
        cfg = dataclasses.replace(base, **over, match=match)
        drive = map_drive(args.sim_length, args.seed, args.map, args.route, gyro=args.imu, config=cfg)
    except (SageError, json.JSONDecodeError, TypeError) as exc:  # a bad map, route or --set
        raise SystemExit(f"slam_edge_diagnosis: {exc}") from None
    slam, truth = drive.slam, drive.truth
    truth_kf = [truth[round(kf.stamp / SCAN_PERIOD_S)] for kf in slam.keyframes]
    report: dict[str, Any] = {
        "map": str(drive.path),
        "seed": args.seed,
        "gyro": args.imu,
        "keyframes": len(slam.keyframes),
        "loop_closures": slam.loop_closures,
        "ate_aligned_rmse_m": trajectory_error(slam, slam.graph.poses, truth),
        "edges": edge_table(slam, truth_kf),
    }
    if args.floor:
        report["floor"] = floor(slam, truth_kf, truth)
    if args.oracle:
        report["oracle"] = oracle(slam, truth_kf, truth)
    if args.segment > 0:
        report["segments"] = segments(slam, truth_kf, args.segment)
    print(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
