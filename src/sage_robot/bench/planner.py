"""Global planner speed: the longest route between places, and 100 random pairs; and the
controller's step time along that route.

Plans on the inflated static costmap exactly as the navigator does (coarse grid on large
maps, then smoothing). Times are wall-clock per plan, in ms.
"""

from __future__ import annotations

import argparse
import itertools
import time
from typing import Any

import numpy as np

LONGEST_REPEATS = 20  # times the longest route is planned
CONTROLLER_STEPS = 400  # controller steps timed along the longest route (20 s at 20 Hz)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--map", default="", help="map YAML (default: the shipped building)")
    p.add_argument("--waypoints", default="", help="waypoints YAML (default: beside the map)")
    p.add_argument("--pairs", type=int, default=100, help="random free-cell pairs to plan")
    p.add_argument("--seed", type=int, default=0, help="random seed")


def _ms(samples: list[float]) -> dict[str, float]:
    a = np.array(samples) * 1000.0
    return {"median_ms": round(float(np.median(a)), 2), "p95_ms": round(float(np.percentile(a, 95)), 2),
            "max_ms": round(float(a.max()), 2)}


def drivable_cells(cm: Any, places: list[Any]) -> np.ndarray:
    """Free cells (cost 0) of the region the places are in (most places), else the largest
    free region: a map may be "free" outside its building too."""
    from scipy import ndimage

    labels, _ = ndimage.label(cm.cost == 0)
    votes = []
    for p in places:
        r, c = cm.geom.to_cell(p.pose.x, p.pose.y)
        if bool(cm.geom.inside(r, c)) and labels[int(r), int(c)] > 0:
            votes.append(int(labels[int(r), int(c)]))
    if votes:
        region = max(set(votes), key=votes.count)
    else:
        region = int(np.argmax(np.bincount(labels.ravel())[1:])) + 1
    return np.argwhere(labels == region)


def _controller(cm: Any, route: Any, settings: Any) -> dict[str, float]:
    """Regulated Pure Pursuit steps along a route with a 6 m local costmap, as the navigator
    runs them (the local costmap is rebuilt per scan, not per step, so it is not timed)."""
    import math

    from sage_robot.nav.controller import ControllerParams, PurePursuit

    nav, robot = settings.nav, settings.robot
    params = ControllerParams(robot.max_linear_mps, robot.max_angular_radps, nav.lookahead_m)
    ctl = PurePursuit(route.points, params, None)
    pose = (float(route.points[0, 0]), float(route.points[0, 1]), 0.0)
    local = cm.window(pose[0], pose[1], nav.local_costmap_m)
    times = []
    dt = 1.0 / nav.controller_hz
    for k in range(CONTROLLER_STEPS):
        if k % 2 == 0:
            local = cm.window(pose[0], pose[1], nav.local_costmap_m)
        t = time.perf_counter()
        cmd = ctl.step(pose, local)
        times.append(time.perf_counter() - t)
        if cmd.arrived:
            break
        x, y, th = pose
        pose = (x + cmd.v * dt * math.cos(th), y + cmd.v * dt * math.sin(th), th + cmd.w * dt)
    return {"steps": len(times), **_ms(times)}


def run(args: argparse.Namespace) -> dict[str, Any]:
    from sage_robot.core.config import Settings
    from sage_robot.nav.mapdata import load_for
    from sage_robot.nav.planner import MAX_FINE_CELLS, NoPath, _astar_backend, plan

    settings = Settings.model_validate({"nav": {"map": args.map, "waypoints": args.waypoints}})
    data = load_for(settings)
    t0 = time.perf_counter()
    cm = data.costmap(settings.robot.radius_m, settings.nav.inflation_radius_m,
                      settings.nav.cost_scaling_factor)
    build_s = time.perf_counter() - t0
    out: dict[str, Any] = {
        "bench": "planner",
        "map": str(data.path),
        "cells": list(cm.geom.shape),
        "resolution_m": cm.geom.resolution,
        "backend": "pyastar2d" if _astar_backend() is not None else "skimage.graph.MCP_Geometric",
        "coarse_factor": max(1, int(np.ceil(np.sqrt(cm.geom.shape[0] * cm.geom.shape[1] / MAX_FINE_CELLS)))),
        "costmap_build_s": round(build_s, 3),
    }
    places = list(data.places)
    if len(places) >= 2:
        best, best_len = None, -1.0
        for a, b in itertools.combinations(places, 2):
            try:
                length = plan(cm, (a.pose.x, a.pose.y), (b.pose.x, b.pose.y)).length_m
            except NoPath:
                continue
            if length > best_len:
                best, best_len = (a, b), length
        if best is not None:
            a, b = best
            times = []
            for _ in range(LONGEST_REPEATS):
                t = time.perf_counter()
                plan(cm, (a.pose.x, a.pose.y), (b.pose.x, b.pose.y))
                times.append(time.perf_counter() - t)
            out["longest_route"] = {"from": a.name, "to": b.name, "length_m": round(best_len, 2),
                                    **_ms(times)}
            out["controller_step"] = _controller(cm, plan(cm, (a.pose.x, a.pose.y), (b.pose.x, b.pose.y)),
                                                 settings)
    cells = drivable_cells(cm, places)
    rng = np.random.default_rng(args.seed)
    times, lengths, failed = [], [], 0
    for _ in range(args.pairs):
        (r0, c0), (r1, c1) = cells[rng.integers(len(cells), size=2)]
        s, g = cm.geom.to_world(r0, c0), cm.geom.to_world(r1, c1)
        t = time.perf_counter()
        try:
            p = plan(cm, (float(s[0]), float(s[1])), (float(g[0]), float(g[1])))
        except NoPath:
            failed += 1
            continue
        times.append(time.perf_counter() - t)
        lengths.append(p.length_m)
    if times:
        out["random_pairs"] = {"pairs": args.pairs, "failed": failed,
                               "mean_length_m": round(float(np.mean(lengths)), 2), **_ms(times)}
    return out
