"""Offline SLAM over a CARMEN log: the same :class:`Slam` as online, fed from the log's scans."""

from __future__ import annotations

import itertools
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from sage_robot.nav.slam.carmen import CarmenLog, LogScan, read_log
from sage_robot.nav.slam.engine import Slam, SlamConfig
from sage_robot.nav.slam.points import Scan
from sage_robot.nav.slam.posegraph import KIND_LOOP, KIND_ODOM, KIND_SCAN, PoseGraph

RANGE_MIN_M = 0.05  # readings closer than this are noise
REPORT_DIGITS = 4  # decimals of the quality report's residuals


@dataclass
class ReplayResult:
    slam: Slam
    log: CarmenLog
    seconds: float  # processing time (wall clock), s
    cpu_seconds: float = 0.0  # CPU time of this process meanwhile, s

    @property
    def realtime_factor_cpu(self) -> float:
        """As :attr:`realtime_factor` with CPU time: what one free core gives on a busy machine."""
        return self.log.duration_s / self.cpu_seconds if self.cpu_seconds > 0 else float("inf")

    @property
    def realtime_factor(self) -> float:
        """How many times faster than the log's real duration the replay ran."""
        return self.log.duration_s / self.seconds if self.seconds > 0 else float("inf")


def to_scan(s: LogScan) -> Scan:
    return Scan(s.ranges, s.angles, RANGE_MIN_M, s.range_max, s.laser_offset)


def replay_log(
    log: CarmenLog | str | Path,
    config: SlamConfig | None = None,
    limit: int | None = None,
    progress: bool = False,
    odom_noise: tuple[float, float] | None = None,
    seed: int = 0,
) -> ReplayResult:
    """Run SLAM over a log's scans (the first ``limit`` of them).

    ``odom_noise`` = (fraction of each step's translation, rad per rad turned): corrupt the
    log's odometry increments with Gaussian noise of that size, e.g. to use a SLAM-corrected
    log as ground truth (drawn from ``numpy.random.default_rng(seed)``).
    """
    if not isinstance(log, CarmenLog):
        log = read_log(log, progress=progress)
    scans = log.scans[:limit] if limit else log.scans
    odoms = [s.odom for s in scans]
    if odom_noise is not None:
        odoms = noisy_odometry(odoms, odom_noise, np.random.default_rng(seed))
    slam = Slam(config, initial_pose=scans[0].odom)
    it = scans
    if progress:
        from tqdm import tqdm

        it = tqdm(scans, desc="SLAM", unit=" scans")
    t0, c0 = time.perf_counter(), time.process_time()
    for s, odom in zip(it, odoms, strict=False):
        slam.add_scan(s.stamp, odom, to_scan(s))
        if progress:
            it.set_postfix(kf=len(slam.keyframes), loops=slam.loop_closures, refresh=False)  # type: ignore[attr-defined]
    slam.finish()
    seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
    used = CarmenLog(log.path, scans, log.odoms, log.params)
    return ReplayResult(slam, used, seconds, cpu)


def noisy_odometry(
    odoms: list[tuple[float, float, float]], noise: tuple[float, float], rng: np.random.Generator
) -> list[tuple[float, float, float]]:
    """Re-integrate odometry increments with multiplicative Gaussian noise plus a small bias."""
    from sage_robot.core.geometry import compose, relative

    frac, rot = noise
    out = [odoms[0]]
    for a, b in itertools.pairwise(odoms):
        dx, dy, dth = relative(a, b)
        dist = float(np.hypot(dx, dy))
        dx += rng.normal(0.0, frac * dist + 1e-4)
        dy += rng.normal(0.0, frac * dist + 1e-4)
        dth += rng.normal(0.0, rot * abs(dth) + 0.2 * frac * dist + 1e-4)
        out.append(compose(out[-1], (dx, dy, dth)))
    return out


def edge_residuals(graph: PoseGraph) -> tuple[np.ndarray, np.ndarray]:
    """Per edge, at the current poses: |translation| (m) and |rotation| (rad) of
    ``⊖z ⊕ (⊖x_i ⊕ x_j)``, the part of the measured relative pose the graph does not honour."""
    from sage_robot.core.geometry import relative

    trans, rot = [], []
    for e in graph.edges:
        dx, dy, dth = relative(e.z, relative(graph.poses[e.i], graph.poses[e.j]))
        trans.append(math.hypot(dx, dy))
        rot.append(abs(dth))
    return np.asarray(trans), np.asarray(rot)


def _stats(values: np.ndarray, scale: float = 1.0) -> dict[str, float]:
    if values.size == 0:
        return {"mean": 0.0, "max": 0.0}
    return {"mean": round(float(values.mean()) * scale, REPORT_DIGITS),
            "max": round(float(values.max()) * scale, REPORT_DIGITS)}  # fmt: skip


def quality_report(slam: Slam) -> dict[str, Any]:
    """How good the optimised pose graph is: keyframes, distance driven, loop closures (accepted,
    tried, rejected), gyro-turned odometry edges weakened for a wheel slip and, per edge kind
    (odom / scan / loop), the count, the Mahalanobis error (``chi``) and the metric residuals
    (``residual_m``, ``residual_deg``: mean and max)."""
    graph = slam.graph
    chi = graph.edge_errors()
    trans, rot = edge_residuals(graph)
    kinds = np.array([e.kind for e in graph.edges])
    _, poses = slam.trajectory_array()
    distance = float(np.hypot(*np.diff(poses[:, :2], axis=0).T).sum()) if len(poses) > 1 else 0.0
    edges = {}
    for kind in (KIND_ODOM, KIND_SCAN, KIND_LOOP):
        sel = kinds == kind
        edges[kind] = {
            "count": int(sel.sum()),
            "chi": _stats(chi[sel]),
            "residual_m": _stats(trans[sel]),
            "residual_deg": _stats(rot[sel], math.degrees(1.0)),
        }
    return {
        "keyframes": len(slam.keyframes),
        "distance_m": round(distance, 2),
        "loop_closures": slam.loop_closures,
        "loop_attempts": slam.loop_attempts,
        "loops_rejected": slam.loops_rejected,
        "optimizations": slam.optimizations,
        "odometry_slips": slam.odometry_slips,
        "doubtful_turns": slam.doubtful_turns,
        "edges": edges,
    }


def format_report(report: dict[str, Any]) -> str:
    """The quality report in a few lines for a person."""
    lines = [
        f"quality: {report['keyframes']} keyframes over {report['distance_m']} m, "
        f"{report['loop_closures']} loops closed ({report['loop_attempts']} tried, "
        f"{report['loops_rejected']} rejected by the optimised graph), "
        f"{report['optimizations']} optimisations",
        "  residuals of the optimised graph (mean / max):",
    ]
    for kind, e in report["edges"].items():
        if not e["count"]:
            lines.append(f"    {kind:<5} edges: none")
            continue
        lines.append(
            f"    {kind:<5} edges: {e['count']:>5}  {e['residual_m']['mean'] * 100:.2f} / "
            f"{e['residual_m']['max'] * 100:.2f} cm  {e['residual_deg']['mean']:.3f} / "
            f"{e['residual_deg']['max']:.3f} deg  chi {e['chi']['mean']:.2f} / {e['chi']['max']:.2f}"
        )
    return "\n".join(lines)
