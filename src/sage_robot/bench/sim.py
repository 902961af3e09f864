"""Simulator speed: ms per 360-beam scan and per camera frame, world (+ firmware model) steps
per second and real-time factor, and the real-time factor of the running simulator nodes.

Heavy packages are imported inside ``run``.
"""

from __future__ import annotations

import argparse
import asyncio
import math
import time
from typing import Any

import numpy as np

STEP_S = 0.01  # the simulator's physics step
SCAN_EVERY = 10  # steps per lidar scan (10 Hz)
CMD_EVERY = 5  # steps per /cmd_vel frame into the firmware model (20 Hz, as the serial bridge)
SCAN_POSES = 40
BENCH_START = (5.0, 40.0, 0.0)  # west end of the east-west corridor, facing east
BENCH_SPEED_MPS = 0.5
WEAVE_RADPS, WEAVE_HZ = 0.05, 0.1  # a gentle weave (heading +-0.08 rad) while driving east


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--seconds", type=float, default=30.0, help="simulated seconds per stepping case")
    p.add_argument("--pedestrians", type=int, default=6, help="simulated people")
    p.add_argument("--no-system", action="store_true", help="skip the run of the real nodes")


def _percentiles(ms: list[float]) -> dict[str, float]:
    a = np.array(ms)
    return {"p50": round(float(np.percentile(a, 50)), 3), "p95": round(float(np.percentile(a, 95)), 3)}


def _poses(world: Any, rng: np.random.Generator, n: int) -> list[tuple[float, float, float]]:
    lanes = world.crowd.lanes
    out = []
    for _ in range(n):
        x, y, _ = lanes.random_point(rng, 0.5)
        out.append((x, y, float(rng.uniform(-math.pi, math.pi))))
    return out


def _time_sensors(world: Any) -> dict[str, Any]:
    rng = np.random.default_rng(0)
    scan_ms: list[float] = []
    cam_ms: list[float] = []
    for pose in _poses(world, rng, SCAN_POSES):
        world.x, world.y, world.theta = pose
        t0 = time.perf_counter()
        world.scan(0.0)
        scan_ms.append((time.perf_counter() - t0) * 1e3)
        if len(cam_ms) < SCAN_POSES // 2:
            t0 = time.perf_counter()
            world.camera_msg(0.0)
            cam_ms.append((time.perf_counter() - t0) * 1e3)
    return {"scan_ms": _percentiles(scan_ms), "camera_frame_ms": _percentiles(cam_ms)}


def _stepping(settings: Any, seconds: float, with_mcu: bool) -> dict[str, Any]:
    from sage_robot.hardware.mcu import protocol as proto
    from sage_robot.sim.firmware import FirmwareModel, FirmwareParams
    from sage_robot.sim.scenario import Scenario
    from sage_robot.sim.setup import build_world

    world = build_world(settings, Scenario(start=BENCH_START))
    fw = FirmwareModel(FirmwareParams(track_width_m=settings.robot.track_width_m), np.random.default_rng(1))
    steps = round(seconds / STEP_S)
    t0, cpu0 = time.perf_counter(), time.process_time()
    for k in range(steps):
        now = k * STEP_S
        turn = WEAVE_RADPS * math.cos(now * WEAVE_HZ * 2 * math.pi)  # weave down the corridor
        if with_mcu:
            if k % CMD_EVERY == 0:
                fw.receive(proto.encode(proto.CMD, (BENCH_SPEED_MPS, turn)))
            wheels = fw.control_step(STEP_S, now)
            v, w = world.body.step(STEP_S, wheels)
            fw.sense(STEP_S, v, w)
            fw.transmit(now)
        else:
            world.move(STEP_S, BENCH_SPEED_MPS, turn)
        world.step(STEP_S)
        if k % SCAN_EVERY == 0:
            world.scan(now)
    wall, cpu = time.perf_counter() - t0, time.process_time() - cpu0
    return {
        "steps_per_s": round(steps / wall),
        "real_time_factor": round(steps * STEP_S / wall, 1),
        # per second of CPU this process got: what an unshared core would give
        "real_time_factor_cpu": round(steps * STEP_S / cpu, 1),
        "distance_m": round(world.distance_m, 1),
        "collisions": world.collisions,
    }


SYSTEM_NODES = ("sim_world", "mcu_sim", "serial_bridge")
# The whole driving stack of `sage sim` (no voice, brain or knowledge base): world, firmware
# model, serial bridge, localization, navigator, web server; the robot drives to a place.
FULL_NODES = (*SYSTEM_NODES, "heartbeat", "battery_watchdog", "map_server", "localization",
              "navigator", "web")
GOAL_AFTER_S = 1.0  # simulated time after start when the goal is sent
# The real-time factors are measured from this simulated time on: the nodes' start-up work
# (localization's distance field, ~1 s, a lockstep job the first steps wait for) is not
# the running stack's speed.
WARM_UP_S = 1.0
FULL_GOAL = "3D_PRINTING_LAB"  # a place of the shipped building the robot drives to


async def _system(settings: Any, seconds: float, nodes: tuple[str, ...], goal: str = "") -> dict[str, Any]:
    """The named nodes of the sim profile on the simulated clock, as fast as possible."""
    from sage_robot.app.runtime import make_context, run_launcher, specs_for
    from sage_robot.core import topics
    from sage_robot.core.msgs.nav import NavigateGoal
    from sage_robot.core.node import SIM_STEP_HOOKS
    from sage_robot.sim.node import WORLD_RESOURCE

    ctx = make_context(settings, simulated=True)
    specs = [s for s in specs_for("sim") if s.name in nodes]
    marks: dict[str, float] = {}
    tasks: list[asyncio.Task[None]] = []

    def mark(_dt: float) -> None:
        now = ctx.clock.now()
        if "first" not in marks and now >= WARM_UP_S - 0.5 * STEP_S:
            marks["first"], marks["cpu_first"] = time.perf_counter(), time.process_time()
            marks["loop_first"], marks["sim_first"] = time.thread_time(), now
        elif now >= seconds - 1.5 * STEP_S and "last" not in marks:  # the last step
            marks["last"], marks["cpu_last"] = time.perf_counter(), time.process_time()
            marks["loop_last"] = time.thread_time()
            marks["distance_m"] = ctx.resources[WORLD_RESOURCE].distance_m

    async def after_start(_launcher: Any) -> None:
        ctx.resources[SIM_STEP_HOOKS].append(mark)
        if goal:  # once the nodes are up (they start on the running clock)
            tasks.append(asyncio.get_running_loop().create_task(send_goal()))

    async def send_goal() -> None:
        await ctx.clock.sleep(GOAL_AFTER_S)
        await ctx.bus.actions.send_goal(topics.NAVIGATE_TO, NavigateGoal(place=goal))

    await run_launcher(ctx, specs, until=seconds, after_start=after_start)
    wall, cpu = marks["last"] - marks["first"], marks["cpu_last"] - marks["cpu_first"]
    measured = seconds - marks["sim_first"]  # simulated seconds between the marks
    return {
        "nodes": [s.name for s in specs],
        "real_time_factor": round(measured / wall, 1) if wall else None,
        "real_time_factor_cpu": round(measured / cpu, 1) if cpu else None,
        # the event loop's own CPU (the stepper and every node's callbacks) and the wall time
        # beyond it: waiting for offloaded jobs, or for a core on a busy machine
        "loop_cpu_s": round(marks["loop_last"] - marks["loop_first"], 2),
        "wall_s": round(wall, 2),
        "distance_m": round(marks["distance_m"], 1),
    }


def run(args: argparse.Namespace) -> dict[str, Any]:
    from sage_robot.core.config import load_profile
    from sage_robot.sim.setup import build_world

    settings = load_profile(None, {"sim": {"pedestrians": args.pedestrians, "speed": None, "camera_hz": 0}})
    t0 = time.perf_counter()
    world = build_world(settings)
    build_s = time.perf_counter() - t0
    result: dict[str, Any] = {
        "bench": "sim",
        "map_cells": [world.grid.width, world.grid.height],
        "beams": world.lidar.spec.beams,
        "pedestrians": len(world.crowd.people),
        "world_build_s": round(build_s, 2),
        **_time_sensors(world),
        "world": _stepping(settings, args.seconds, with_mcu=False),
        "world_mcu": _stepping(settings, args.seconds, with_mcu=True),
    }
    if not args.no_system:
        result["system"] = asyncio.run(_system(settings, args.seconds, SYSTEM_NODES))
        full = load_profile(None, {"sim": {"pedestrians": args.pedestrians, "speed": None, "camera_hz": 0},
                                   "web": {"port": 0}})
        result["full_stack"] = {**asyncio.run(_system(full, args.seconds, FULL_NODES, FULL_GOAL)),
                                "goal": FULL_GOAL}
    return result
