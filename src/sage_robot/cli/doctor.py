"""`sage doctor`: check this machine and the robot, and say how to fix what is missing."""

from __future__ import annotations

import argparse
import platform
import sys
from collections.abc import Callable
from dataclasses import dataclass

from sage_robot.core.config import load_profile
from sage_robot.core.errors import ConfigError


@dataclass
class Check:
    name: str
    ok: bool
    detail: str
    fix: str = ""
    essential: bool = True


def check_python() -> Check:
    ok = sys.version_info >= (3, 10)
    return Check("python", ok, platform.python_version(), "install Python 3.10 or newer")


def check_profile(path: str | None) -> Check:
    try:
        load_profile(path)
        return Check("profile", True, path or "built-in simulated robot")
    except ConfigError as exc:
        return Check("profile", False, str(exc), "fix the profile as the message says")


CHECKS: list[Callable[[argparse.Namespace], Check]] = [
    lambda a: check_python(),
    lambda a: check_profile(a.profile),
]


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser("doctor", help="check devices, models, ports and network; explain fixes")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    results = [c(args) for c in CHECKS]
    for r in results:
        mark = "ok  " if r.ok else ("FAIL" if r.essential else "warn")
        print(f"[{mark}] {r.name:<12} {r.detail}")
        if not r.ok and r.fix:
            print(f"       fix: {r.fix}")
    return 1 if any(not r.ok and r.essential for r in results) else 0
