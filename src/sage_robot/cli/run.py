"""`sage sim` and `sage up`: start the robot's nodes, simulated or real.

``sage sim`` runs every node of the "sim" profile on the simulated clock (real time by
default, ``--speed N`` or ``--fast``) and prints the web pages' addresses.
``sage sim --headless --scenario FILE`` runs a scenario without the web server and
prints a summary (collisions, distance, time) when it ends.
"""

from __future__ import annotations

import argparse
import asyncio
import importlib
import json
import os
import sys
import time
from typing import Any

from sage_robot.app.runtime import make_context, run_launcher, specs_for
from sage_robot.app.supervisor import SUPERVISED_ENV, supervise
from sage_robot.cli.processes import add_process_flags, run_as_processes, wants_processes
from sage_robot.core.config import Settings, load_profile
from sage_robot.core.errors import ConfigError

HEADLESS_SKIP = {"web", "foxglove"}  # network listeners: a headless run opens none
WEB_NODE = "web"
ROS2_NODE = "ros2_bridge"  # `--ros2`: the topics on a ROS 2 network too (rmw_zenoh), docs/operations.md
ROS2_HELP = "also bridge the topics to ROS 2 over Zenoh (rmw_zenoh; ROS_DOMAIN_ID, SAGE_ROS2_CONNECT)"


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser("sim", help="start the whole system on the simulated robot (default demo)")
    p.add_argument("--speed", type=float, help="real-time factor (default from the profile: 1)")
    p.add_argument("--fast", action="store_true", help="run as fast as the machine allows")
    p.add_argument("--headless", action="store_true", help="no web server; print a summary at the end")
    p.add_argument("--scenario", help="scenario YAML (people, clutter, start, timed events)")
    p.add_argument("--duration", type=float, help="stop after this many simulated seconds")
    p.add_argument("--seed", type=int, help="world random seed")
    p.add_argument("--json", action="store_true", help="print the summary as one JSON line")
    p.add_argument("--nodes", help="run only these nodes of the sim profile (comma-separated)")
    p.add_argument("--ros2", action="store_true", help=ROS2_HELP)
    add_process_flags(p)
    p.set_defaults(func=run_sim)

    p = sub.add_parser("up", help="start the real robot's nodes from the profile")
    p.add_argument("--mode", default="tour", choices=["tour", "slam"], help="what the robot does")
    p.add_argument(
        "--imu", action="store_true", help="publish /imu/data and fuse it (the seed's *_with_imu.sh scripts)"
    )
    p.add_argument(
        "--no-supervisor",
        action="store_true",
        help="run without the parent process that stops the motors when SAGE dies or freezes "
        "(only where something else does that job, e.g. systemd's ExecStopPost)",
    )
    p.add_argument("--ros2", action="store_true", help=ROS2_HELP)
    add_process_flags(p)
    p.set_defaults(func=run_up)


def _merge(base: dict[str, Any], extra: dict[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for key, value in extra.items():
        out[key] = (
            _merge(out[key], value) if isinstance(value, dict) and isinstance(out.get(key), dict) else value
        )
    return out


def _overrides(args: argparse.Namespace, scenario: Any) -> dict[str, Any]:
    sim: dict[str, object] = {}
    if args.speed is not None:
        if args.speed <= 0:
            raise ConfigError(f"--speed must be > 0, got {args.speed}")
        sim["speed"] = args.speed
    if args.fast:
        sim["speed"] = None
    if args.seed is not None:
        sim["seed"] = args.seed
    if args.headless:
        sim["camera_hz"] = 0  # nobody can watch: no frames rendered at all
    base = scenario.settings_overrides() if scenario is not None else {}
    return _merge(base, {"sim": sim} if sim else {})


def web_addresses(settings: Settings) -> list[str]:
    """The pages the web node serves, as URLs on this machine (https when ``web.tls`` says so)."""
    from sage_robot.web.tls import tls_enabled

    base = f"{'https' if tls_enabled(settings.web) else 'http'}://localhost:{settings.web.port}"
    try:
        app = importlib.import_module("sage_robot.web.app")
        pages = list(getattr(app, "PUBLIC_PAGES", {})) + list(getattr(app, "OPERATOR_PAGES", {}))
    except ImportError:
        pages = ["/"]
    return [f"{base}{p}" for p in pages if p != "/login"] or [f"{base}/"]


def sim_specs(headless: bool, nodes: str | None = None) -> list[Any]:
    """The sim profile's node specs; ``headless`` leaves out every network listener
    (web, Foxglove) so one-shot runs can run side by side; ``nodes``: a comma-separated
    selection."""
    specs = [s for s in specs_for("sim") if not (headless and s.name in HEADLESS_SKIP)]
    if nodes:
        wanted = [n.strip() for n in nodes.split(",") if n.strip()]
        unknown = sorted(set(wanted) - {s.name for s in specs})
        if unknown:
            raise ConfigError(
                f"--nodes: {', '.join(unknown)} not in the sim profile"
                f"{' (headless runs open no listeners)' if headless else ''}; it has "
                f"{', '.join(s.name for s in specs)}"
            )
        specs = [s for s in specs if s.name in wanted]
    return specs


def ros2_specs(mode: str) -> list[Any]:
    """The ROS 2 bridge's node spec (``--ros2``); its environment is checked here, so a bad
    ``ROS_DOMAIN_ID`` is a one-line error at start, not a node that keeps failing."""
    spec = specs_for(mode, [ROS2_NODE])[-1]  # a clear error when the ops extra is missing
    from sage_robot.app.ros2_bridge import Ros2BridgeSettings

    Ros2BridgeSettings.from_env(os.environ)
    return [spec]


def run_sim(args: argparse.Namespace) -> int:
    from sage_robot.sim.node import SCENARIO_RESOURCE, SUMMARY_RESOURCE, WORLD_RESOURCE
    from sage_robot.sim.scenario import load_scenario

    scenario = load_scenario(args.scenario) if args.scenario else None
    settings = load_profile(args.profile, _overrides(args, scenario) or None)
    duration = args.duration if args.duration is not None else (scenario.duration_s if scenario else None)
    if duration is not None and duration <= 0:
        raise ConfigError(f"--duration must be > 0 s, got {duration}")
    if wants_processes(args):  # each process group in its own process (cli/processes.py)
        extra = ros2_specs("sim") if getattr(args, "ros2", False) else []
        specs = sim_specs(args.headless, args.nodes) + extra
        pages = web_addresses(settings) if WEB_NODE in {s.name for s in specs} else None
        return run_as_processes(args, settings, "sim", specs, _overrides(args, scenario), pages)
    ctx = make_context(settings, simulated=True)
    if scenario is not None:
        ctx.resources[SCENARIO_RESOURCE] = scenario
    specs = sim_specs(args.headless, args.nodes)
    if getattr(args, "ros2", False):
        specs += ros2_specs("sim")
    names = [s.name for s in specs]
    speed = "as fast as possible" if settings.sim.speed is None else f"{settings.sim.speed:g}x real time"
    if not args.json:
        print(f"SAGE simulator: {len(specs)} nodes ({', '.join(names)}), {speed}; Ctrl-C to stop")
        if WEB_NODE in names:
            print("web pages:")
            for url in web_addresses(settings):
                print(f"  {url}")
    wall0 = time.monotonic()
    launcher = asyncio.run(run_launcher(ctx, specs, until=duration))
    wall = time.monotonic() - wall0
    world = ctx.resources.get(WORLD_RESOURCE)
    sim_t = ctx.clock.now()
    summary: dict[str, Any] = {
        "scenario": scenario.name if scenario else None,
        "sim_time_s": round(sim_t, 3),
        "wall_time_s": round(wall, 3),
        "real_time_factor": round(sim_t / wall, 2) if wall > 0 else None,
        "nodes_restarted": sorted(n for n, h in launcher.health.items() if h.restarts),
        "nodes_failed": sorted(n for n, h in launcher.health.items() if h.last_error),
    }
    if world is not None:
        ws = world.summary()
        ws.pop("sim_time_s", None)
        summary.update(ws)
    results = ctx.resources.get(SUMMARY_RESOURCE, {})
    summary["goals"] = results.get("goals", [])
    summary["conversations"] = results.get("conversations", [])
    summary["arrivals"] = results.get("arrivals", [])
    _print_summary(summary, args.json)
    return 0 if world is not None else 1


def _print_summary(summary: dict[str, Any], as_json: bool) -> None:
    if as_json:
        print(json.dumps(summary))
        return
    print(
        f"simulated {summary['sim_time_s']:.1f} s in {summary['wall_time_s']:.1f} s "
        f"({summary['real_time_factor']}x real time)"
    )
    if "distance_m" in summary:
        kinds = summary["collisions_by_kind"]
        print(
            f"robot drove {summary['distance_m']:.2f} m, collisions: {summary['collisions']}"
            f"{' ' + str(kinds) if kinds else ''}, final pose {summary['pose']}"
        )
    for goal in summary["goals"]:
        print(f"goal {goal['goal']}: {goal.get('status', 'running')} {goal.get('message', '')}".rstrip())
    for talk in summary.get("conversations", []):
        replies = " ".join(talk.get("replies", []))
        print(f"heard {talk['heard']!r}: {talk.get('status', 'running')} {replies!r}")
    for arrival in summary.get("arrivals", []):
        print(f"arrived at {arrival['place']} at {arrival['at_s']:.1f} s")
    print(f"nodes restarted: {', '.join(summary['nodes_restarted']) or 'none'}")


def run_up(args: argparse.Namespace) -> int:
    imu = {"mcu": {"imu_enabled": True}, "nav": {"use_ekf": True}} if args.imu else None
    settings = load_profile(args.profile, imu)
    if not args.no_supervisor and not os.environ.get(SUPERVISED_ENV):
        # This process becomes the supervisor; the robot runs in a child that it watches.
        child = [sys.executable, "-m", "sage_robot.cli.main", *sys.argv[1:]]
        return supervise(child, settings.mcu.port, settings.mcu.baud, firmware=settings.mcu.firmware)
    if wants_processes(args):
        extra = ros2_specs(args.mode) if getattr(args, "ros2", False) else []
        return run_as_processes(args, settings, args.mode, specs_for(args.mode) + extra, imu or {})
    ctx = make_context(settings, simulated=False)
    extra = ros2_specs(args.mode) if getattr(args, "ros2", False) else []
    asyncio.run(run_launcher(ctx, specs_for(args.mode) + extra))
    return 0
