"""`sage sim` and `sage up`: start the robot's nodes, simulated or real."""

from __future__ import annotations

import argparse
import asyncio

from sage_robot.app.runtime import make_context, run_launcher, specs_for
from sage_robot.core.config import load_profile


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser("sim", help="start the whole system on the simulated robot (default demo)")
    p.add_argument("--speed", type=float, help="real-time factor (default from the profile: 1)")
    p.add_argument("--fast", action="store_true", help="run as fast as the machine allows")
    p.add_argument("--headless", action="store_true", help="no web server; print a summary")
    p.add_argument("--duration", type=float, help="stop after this many simulated seconds")
    p.add_argument("--seed", type=int, help="world random seed")
    p.set_defaults(func=run_sim)

    p = sub.add_parser("up", help="start the real robot's nodes from the profile")
    p.add_argument("--mode", default="tour", choices=["tour", "slam"], help="what the robot does")
    p.set_defaults(func=run_up)


def run_sim(args: argparse.Namespace) -> int:
    sim: dict[str, object] = {}
    if args.speed is not None:
        sim["speed"] = args.speed
    if args.fast:
        sim["speed"] = None
    if args.seed is not None:
        sim["seed"] = args.seed
    settings = load_profile(args.profile, {"sim": sim} if sim else None)
    ctx = make_context(settings, simulated=True)
    specs = specs_for("sim")
    print(f"SAGE simulator: {len(specs)} nodes; Ctrl-C to stop")
    launcher = asyncio.run(run_launcher(ctx, specs, until=args.duration))
    bad = [n for n, h in launcher.health.items() if h.restarts]
    print(f"simulated {ctx.clock.now():.1f} s; nodes restarted: {', '.join(bad) or 'none'}")
    return 0


def run_up(args: argparse.Namespace) -> int:
    settings = load_profile(args.profile)
    ctx = make_context(settings, simulated=False)
    asyncio.run(run_launcher(ctx, specs_for(args.mode)))
    return 0
