"""`sage sim --processes` / `sage up --processes`: the nodes as process groups.

``--processes`` runs each group of the profile's ``processes.groups`` in its own process
under one supervisor (:mod:`sage_robot.app.process_groups`): a crashed group is restarted
with backoff and shown in the health pages, the others go on. ``--one-process`` (the
default for now) keeps every node in one process: deterministic, what tests and benchmarks
use.
"""

from __future__ import annotations

import argparse
from typing import Any

from sage_robot.core.config import Settings
from sage_robot.core.errors import ConfigError

ONE_RUN_FLAGS = ("scenario", "duration", "json")  # need the one-process run's summary


def add_process_flags(p: argparse.ArgumentParser) -> None:
    how = p.add_mutually_exclusive_group()
    how.add_argument("--processes", action="store_true",
                     help="run the profile's process groups (processes.groups) under one supervisor "
                     "that restarts a crashed group; they talk over Zenoh on loopback")
    how.add_argument("--one-process", action="store_true",
                     help="every node in this process (the default; deterministic, for tests)")


def wants_processes(args: argparse.Namespace) -> bool:
    return bool(getattr(args, "processes", False))


def run_as_processes(
    args: argparse.Namespace,
    settings: Settings,
    mode: str,
    specs: list[Any],
    overrides: dict[str, Any],
    pages: list[str] | None = None,
) -> int:
    """Run ``specs`` (the one-process run's node specs) as process groups until Ctrl-C;
    ``pages``: the web pages' addresses, printed at the start."""
    from sage_robot.app.process_groups import hub_endpoints, run_processes
    from sage_robot.core.config.processes import group_of

    given = [f"--{f}" for f in ONE_RUN_FLAGS if getattr(args, f, None)]
    if given:
        raise ConfigError(f"--processes runs until Ctrl-C and prints no summary: leave it out for "
                          f"{', '.join(given)}")
    nodes = [(s.name, s.critical) for s in specs]
    groups = group_of(settings.processes.groups, [n for n, _ in nodes])
    print(f"SAGE {mode}: {len(groups)} process groups on Zenoh {hub_endpoints(settings)[0]}; Ctrl-C to stop")
    for name, members in groups.items():
        print(f"  {name}: {', '.join(members)}")
    if pages:
        print("web pages:\n" + "\n".join(f"  {url}" for url in pages))
    supervisor = run_processes(settings, mode, nodes, getattr(args, "profile", None), overrides)
    restarted = sorted(g for g, p in supervisor.groups.items() if p.restarts)
    print(f"process groups restarted: {', '.join(restarted) or 'none'}")
    return 0
