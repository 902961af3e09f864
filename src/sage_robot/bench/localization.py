"""AMCL speed and convergence: update time at 500 and 2000 particles (60 beams), and the
distance to converge from global localization while the robot drives.

Each trial drives a random planned route of ``--drive-m`` from a random drivable cell,
after a global localization from the first scan. *Converged*: the estimate is within 0.5 m
and 0.2 rad of the truth from some point to the end of the drive. *Declared*: the filter's
own verdict as the navigator reads it from ``/localization/health`` (one hypothesis left,
``spread_m`` < 0.5 m, scan fit ≥ 0.75); a *false declaration* is a step declared while the
estimate is wrong: the quality check that must catch a wrong convergence.

Scans come from the simulator's ray caster on the map itself (1 % range noise, as the
simulated RPLIDAR). Update times are wall-clock; convergence is in simulated seconds of
driving at 0.5 m/s (a filter update every 0.25 m, as AMCL's ``update_min_d``).
"""

from __future__ import annotations

import argparse
import math
import time
from typing import Any

import numpy as np

from sage_robot.core.errors import SageError

UPDATES = 100  # timed filter updates per particle count
DRIVE_SPEED_MPS = 0.5
STEP_M = 0.25  # AMCL update_min_d: one filter update per step
CONVERGED_M, CONVERGED_RAD = 0.5, 0.2
DRIVE_M = 20.0  # give up a convergence trial after this much driving (m)
SPIN_STEP_RAD = 0.2  # AMCL update_min_a: one filter update per step when spinning
SPIN_TURNS = 2.0
CLUTTER_SIDE_M = 0.5
CLUTTER_CLEAR_M = 1.5  # boxes stay this far from the trial's route
DECLARE_FIT = 0.75  # the navigator's RELOCALIZED_SCORE: share of returns on mapped walls
RANGE_NOISE = 0.01


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--map", default="", help="map YAML (default: the shipped building)")
    p.add_argument("--beams", type=int, default=60, help="beams per update")
    p.add_argument("--trials", type=int, default=5, help="global-localization trials")
    p.add_argument("--seed", type=int, default=0, help="random seed")
    p.add_argument("--drive-m", type=float, default=DRIVE_M, help="driving allowed per trial (m)")
    p.add_argument("--motion", choices=("drive", "spin"), default="drive",
                   help="drive a route, or spin in place (the navigator's lost recovery)")
    p.add_argument("--turns", type=float, default=SPIN_TURNS, help="turns per trial with --motion spin")
    p.add_argument("--odom-error", type=float, default=0.0,
                   help="wheel odometry reads this fraction long in distance and turn (e.g. 0.02)")
    p.add_argument("--clutter", type=int, default=0,
                   help="unmapped 0.5 m boxes the lidar sees in convergence trials (off the route)")


def _route(cm: Any, rng: np.random.Generator, cells: np.ndarray, length_m: float = DRIVE_M) -> np.ndarray:
    """A drivable route of at least ``length_m`` between two random free cells (x, y points)."""
    from sage_robot.nav.planner import NoPath, plan, resample

    for _ in range(50):
        (r0, c0), (r1, c1) = cells[rng.integers(len(cells), size=2)]
        s, g = cm.geom.to_world(r0, c0), cm.geom.to_world(r1, c1)
        try:
            p = plan(cm, (float(s[0]), float(s[1])), (float(g[0]), float(g[1])))
        except NoPath:
            continue
        if p.length_m >= length_m:
            return resample(p.points, STEP_M)
    raise SageError(f"no route of {length_m:g} m found on this map (try a smaller --drive-m)")


def _cluttered(grid: Any, cells: np.ndarray, cm: Any, route: list[tuple[float, float, float]], k: int,
               rng: np.random.Generator) -> Any:
    """A ray caster on a copy of the map with ``k`` unmapped boxes, none near the route."""
    from sage_robot.core.msgs import OccupancyGrid
    from sage_robot.sim.raycast import GridRaycaster

    data = grid.data.copy()
    pts = np.array([p[:2] for p in route])
    side = max(1, round(CLUTTER_SIDE_M / grid.resolution))
    placed = 0
    for r0, c0 in cells[rng.permutation(len(cells))]:
        x, y = cm.geom.to_world(r0, c0)
        if np.min(np.hypot(pts[:, 0] - x, pts[:, 1] - y)) < CLUTTER_CLEAR_M:
            continue
        data[r0:r0 + side, c0:c0 + side] = 100
        placed += 1
        if placed == k:
            break
    return GridRaycaster(OccupancyGrid(grid.stamp, grid.frame_id, grid.resolution, grid.origin, data))


def _poses(route: np.ndarray) -> list[tuple[float, float, float]]:
    d = np.diff(route, axis=0)
    th = np.arctan2(d[:, 1], d[:, 0])
    return [(float(x), float(y), float(t)) for (x, y), t in zip(route[1:], th, strict=True)]


def run(args: argparse.Namespace) -> dict[str, Any]:
    from sage_robot.bench.planner import drivable_cells
    from sage_robot.core.config import Settings
    from sage_robot.core.geometry import compose, relative, wrap_angle
    from sage_robot.nav.amcl import ParticleFilter, scan_fit
    from sage_robot.nav.mapdata import load_for
    from sage_robot.nav.scanmatch import SignedDistanceField, refine
    from sage_robot.sim.raycast import GridRaycaster

    settings = Settings.model_validate({"nav": {"map": args.map}})
    data = load_for(settings)
    lm = settings.robot.lidar
    mount = (lm.x_m, lm.y_m, lm.yaw_rad)
    caster = GridRaycaster(data.grid)
    angles = -math.pi + 2 * math.pi / 360 * np.arange(360)
    rng = np.random.default_rng(args.seed)
    cm = data.costmap(settings.robot.radius_m, settings.nav.inflation_radius_m,
                      settings.nav.cost_scaling_factor)
    cells = drivable_cells(cm, list(data.places))

    def scan(pose: tuple[float, float, float], by: Any = None) -> np.ndarray:
        lx, ly, lt = compose(pose, mount)
        r = (by or caster).cast(lx, ly, angles + lt, 12.0)
        return (r * (1.0 + RANGE_NOISE * rng.standard_normal(len(r)))).astype(np.float64)

    sdf = SignedDistanceField(data.grid)
    out: dict[str, Any] = {"bench": "localization", "map": str(data.path), "beams": args.beams}
    poses = _poses(_route(cm, rng, cells))
    for n in (500, 2000):
        pf = ParticleFilter(data.grid, np.random.default_rng(args.seed), n, n, mount, args.beams)
        pf.set_pose(*poses[0])
        pf.update(poses[0], angles, scan(poses[0]), 12.0)  # the odometry reference: no update yet
        times, errs, fixed, refine_ms = [], [], [], []
        odom = poses[0]
        for k in range(UPDATES):
            truth = poses[min(k + 1, len(poses) - 1)]
            odom = truth  # perfect odometry here: this measures the filter's cost
            r = scan(truth)
            t = time.perf_counter()
            pf.update(odom, angles, r, 12.0, force=True)
            times.append(time.perf_counter() - t)
            e = pf.estimate()
            errs.append(math.hypot(e.x - truth[0], e.y - truth[1]))
            t = time.perf_counter()
            fix = refine(sdf, (e.x, e.y, e.theta), mount, angles, r, 12.0)  # as the node does
            refine_ms.append((time.perf_counter() - t) * 1000)
            fixed.append(errs[-1] if fix is None else math.hypot(fix.x - truth[0], fix.y - truth[1]))
        a = np.array(times) * 1000
        out[f"update_{n}"] = {"median_ms": round(float(np.median(a)), 2),
                              "p95_ms": round(float(np.percentile(a, 95)), 2),
                              "tracking_error_median_m": round(float(np.median(errs)), 3),
                              "tracking_error_rms_m": round(float(np.sqrt(np.mean(np.square(errs)))), 3),
                              "refined_error_median_m": round(float(np.median(fixed)), 3),
                              "refined_error_rms_m": round(float(np.sqrt(np.mean(np.square(fixed)))), 3),
                              "refine_ms_median": round(float(np.median(refine_ms)), 2)}
    seeds = [(p.pose.x, p.pose.y) for p in data.places]
    # progress per filter update, reported as metres driven or turns spun
    unit, step = ("turns", SPIN_STEP_RAD / (2 * math.pi)) if args.motion == "spin" else ("m", STEP_M)
    nav = settings.nav
    trials: list[dict[str, Any]] = []
    global_ms: list[float] = []
    for _ in range(args.trials):
        route = _poses(_route(cm, rng, cells, args.drive_m))
        world = _cluttered(data.grid, cells, cm, route, args.clutter, rng) if args.clutter > 0 else caster
        pf = ParticleFilter(data.grid, rng, settings.nav.min_particles, settings.nav.max_particles, mount,
                            args.beams, seeds=seeds)
        _ = pf.region  # computed once per map (the node does it at start-up)
        t = time.perf_counter()
        pf.global_localization((angles, scan(route[0], world), 12.0))
        init_s = time.perf_counter() - t
        odom = route[0]
        pf.update(odom, angles, scan(route[0], world), 12.0)  # odometry reference
        correct_from = declared_at = None
        false_declared = 0
        if args.motion == "spin":
            x0, y0, t0 = route[0]
            n_spin = int(args.turns * 2 * math.pi / SPIN_STEP_RAD)
            steps = [(x0, y0, wrap_angle(t0 + k * SPIN_STEP_RAD)) for k in range(1, n_spin + 1)]
        else:
            steps = route[1:int(args.drive_m / STEP_M) + 1]
        prev = route[0]
        for k, truth in enumerate(steps, start=1):
            gain = 1.0 + args.odom_error
            dx, dy, dt = relative(prev, truth)
            odom = compose(odom, (dx * gain, dy * gain, dt * gain))
            prev = truth
            r = scan(truth, world)
            big = pf.count > settings.nav.max_particles
            t = time.perf_counter()
            pf.update(odom, angles, r, 12.0, force=True)
            if big:
                global_ms.append((time.perf_counter() - t) * 1000)
            e = pf.estimate()
            right = (math.hypot(e.x - truth[0], e.y - truth[1]) < CONVERGED_M
                     and abs(wrap_angle(e.theta - truth[2])) < CONVERGED_RAD)
            # the filter's own verdict, as the navigator reads it from /localization/health
            fit = scan_fit(pf.field, (e.x, e.y, e.theta), mount, angles, r, 12.0, nav.health_tolerance_m)
            declared = pf.spread_m() < CONVERGED_M and fit >= DECLARE_FIT
            if declared and declared_at is None:
                declared_at = k
            if declared and not right:
                false_declared += 1
            if right and correct_from is None:
                correct_from = k
            elif not right:
                correct_from = None
        trial: dict[str, Any] = {
            "init_s": round(init_s, 2),
            f"converged_after_{unit}": None if correct_from is None else round(correct_from * step, 2),
            f"declared_after_{unit}": None if declared_at is None else round(declared_at * step, 2),
            "false_declarations": false_declared,
        }
        trials.append(trial)
    done = [t[f"converged_after_{unit}"] for t in trials if t[f"converged_after_{unit}"] is not None]
    out["global_localization"] = {
        "trials": len(trials),
        "motion": args.motion,
        "odom_error": args.odom_error,
        "clutter": args.clutter,
        **({"turns": args.turns} if args.motion == "spin" else {"drive_m": args.drive_m}),
        "converged": len(done),
        f"median_{unit}": round(float(np.median(done)), 2) if done else None,
        f"max_{unit}": round(float(np.max(done)), 2) if done else None,
        **({"median_time_s": round(float(np.median(done)) / DRIVE_SPEED_MPS, 1) if done else None}
           if args.motion == "drive" else {}),
        "declared": sum(t[f"declared_after_{unit}"] is not None for t in trials),
        "trials_with_false_declaration": sum(t["false_declarations"] > 0 for t in trials),
        "median_init_s": round(float(np.median([t["init_s"] for t in trials])), 2),
        "global_phase_update_median_ms": round(float(np.median(global_ms)), 2) if global_ms else None,
        "per_trial": trials,
    }
    return out
