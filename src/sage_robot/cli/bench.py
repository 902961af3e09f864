"""`sage bench NAME --json`: benchmarks that print JSON. Each lives in ``sage_robot.bench``
and provides ``add_arguments(parser)`` and ``run(args) -> dict``."""

from __future__ import annotations

import argparse
import importlib
import json

BENCHMARKS: dict[str, str] = {
    "sim": "sage_robot.bench.sim",
    "bus": "sage_robot.bench.bus",
    "kb": "sage_robot.bench.kb",
    "mcu": "sage_robot.bench.mcu",
    "brain": "sage_robot.bench.brain",
    "voice": "sage_robot.bench.voice",
    "web": "sage_robot.bench.web",
    "safety": "sage_robot.bench.safety",
    "slam": "sage_robot.bench.slam",
    "nav": "sage_robot.bench.nav",
    "localization": "sage_robot.bench.localization",
    "planner": "sage_robot.bench.planner",
}


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser("bench", help="run a benchmark and print JSON")
    p.set_defaults(help_parser=p)
    bsub = p.add_subparsers(dest="bench", metavar="NAME")
    for name, module_name in BENCHMARKS.items():
        try:
            module = importlib.import_module(module_name)
        except ImportError as exc:  # an extra is not installed: say so when it is asked for
            bp = bsub.add_parser(name, help=f"(unavailable: {exc})")
            bp.set_defaults(func=lambda a, e=exc, n=name: _unavailable(n, e))
            continue
        bp = bsub.add_parser(name, help=((module.__doc__ or "").strip().splitlines() or [name])[0])
        bp.add_argument("--json", action="store_true", help="print only the JSON line")
        module.add_arguments(bp)
        bp.set_defaults(func=lambda a, m=module: _run(m, a))


def _unavailable(name: str, exc: ImportError) -> int:
    from sage_robot.core.errors import SageError

    raise SageError(f"benchmark {name!r} cannot run: {exc}; install it with: pip install 'sage-robot[all]'")


def _run(module: object, args: argparse.Namespace) -> int:
    result = module.run(args)  # type: ignore[attr-defined]
    if args.json:
        print(json.dumps(result))
    else:
        print(json.dumps(result, indent=2))
    return 0
