"""`sage version`."""

from __future__ import annotations

import argparse
import platform

from sage_robot import __version__


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser("version", help="print the version")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    print(f"sage-robot {__version__} (Python {platform.python_version()})")
    return 0
