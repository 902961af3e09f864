"""`sage doctor`: check this machine and the robot, and say how to fix what is missing."""

from __future__ import annotations

import argparse
import json

from sage_robot.core.config import load_profile
from sage_robot.core.errors import ConfigError


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser("doctor", help="check devices, models, ports and network; explain fixes")
    p.add_argument("--json", action="store_true", help="print the checks as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from sage_robot.app.doctor import Check, run_checks

    try:
        settings = load_profile(args.profile)
    except ConfigError as exc:
        results = [Check("profile", False, str(exc), "fix the profile as the message says")]
    else:
        results = [Check("profile", True, args.profile or "built-in simulated robot"), *run_checks(settings)]
    if not args.json:
        print("Checking this machine and the real robot's devices "
              "(the simulator, `sage sim`, needs none of them).")
    if args.json:
        print(json.dumps([r.__dict__ for r in results], indent=2))
    else:
        for r in results:
            print(f"[{r.mark:<4}] {r.name:<8} {r.detail}")
            if not r.ok and r.fix:
                print(f"               fix: {r.fix}")
    return 1 if any(not r.ok and r.essential for r in results) else 0
