"""`sage`: one command, one subcommand per task. Each module under ``sage_robot.cli`` in
:data:`COMMANDS` adds its subcommands with ``register(subparsers)`` and imports heavy
packages only when its command runs."""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from sage_robot.core.errors import SageError

COMMANDS = ["run", "doctor", "bench", "version", "ops", "mcu", "kb", "chat", "voice", "slam", "topic"]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="sage",
        description="SAGE, the campus tour robot. `sage sim` starts everything on a simulated "
        "robot; `sage up` on the real one.",
    )
    parser.add_argument("--profile", help="robot profile YAML (default: the simulated robot)")
    parser.add_argument("--log-level", default="INFO", help="DEBUG, INFO, WARNING or ERROR")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        try:
            module = importlib.import_module(f"sage_robot.cli.{name}")
        except ImportError as exc:  # a missing extra must not take the whole command down
            print(f"sage: the '{name}' commands are unavailable: {exc}", file=sys.stderr)
            continue
        module.register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        # A group without a subcommand: show its help.
        (getattr(args, "help_parser", None) or parser).print_help()
        return 0
    from sage_robot.core import log

    log.configure(args.log_level)
    try:
        return int(args.func(args) or 0)
    except SageError as exc:
        print(f"sage: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
