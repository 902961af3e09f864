"""One process group: some of a mode's nodes in a process of their own, on the Zenoh bus.

The process-group supervisor (:mod:`sage_robot.app.process_groups`) starts one of these per
group of the profile's ``processes.groups``::

    python -m sage_robot.app.group_main --group nav --mode sim --nodes map_server,navigator \\
        --connect tcp/127.0.0.1:7447 --clock follow

Its bus is a Zenoh peer that finds the others at the supervisor's router (``--connect``) and
then talks to each directly. ``--clock source`` (the
simulator's group) steps a simulated clock and publishes ``/clock``; ``--clock follow`` takes
time from ``/clock`` (:class:`~sage_robot.core.clock_follow.FollowerClock`); ``--clock wall``
is the real robot's time. With ``--clock-board PATH`` (groups on one machine) the simulator
also writes its time on a shared page at every physics step and the followers read it there
instead of following ``/clock`` (:mod:`sage_robot.core.clock_board`). The group's launcher
reports on ``/sage/group_health/<group>``; the supervisor merges the reports into
``/sage/health``.

In the simulator the MCU's pseudo-terminal lives in the simulator's process: that group keeps
a link to it at ``--export-port`` (moved when the simulator restarts) and the motion group's
serial bridge opens the link (``--mcu-port``).

This module imports what its group's nodes need and nothing more: the motion group stays
small (no ML packages; ``tests/app/test_process_groups.py`` checks it).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import sys
import threading
import time
from pathlib import Path
from typing import Any

from sage_robot.app.launcher import HEALTH_TOPIC, Launcher, NodeSpec
from sage_robot.app.profiles import PROFILES
from sage_robot.app.registry import node_class
from sage_robot.app.runtime import make_transport, run_launcher
from sage_robot.core import event_loop
from sage_robot.core.bus import Bus, Topic
from sage_robot.core.clock import Clock, SimClock, WallClock
from sage_robot.core.clock_board import ClockBoard
from sage_robot.core.clock_follow import FollowerClock, publish_clock
from sage_robot.core.config import Settings, load_profile
from sage_robot.core.errors import ConfigError, SageError
from sage_robot.core.msgs import HealthReport
from sage_robot.core.node import SIM_STEP_HOOKS, NodeContext
from sage_robot.core.realtime import raise_threads, set_fifo
from sage_robot.core.transport.keys import ZENOH_THREADS
from sage_robot.hardware.mcu.bridge import PORT_READ_ELSEWHERE, PORT_RESOURCE

ZENOH_RERAISE_S = 1.0  # how often Zenoh threads started since are raised to their priority

GROUP_HEALTH_PREFIX = "/sage/group_health/"  # + group name: a group's launcher reports here
PORT_WATCH_S = 0.1  # how often the simulator's group checks its pty link (s, its clock)
CLOCK_MODES = ("source", "follow", "wall")
# The simulator's group wakes once per odometry frame (20 ms), stepping the physics and the
# firmware model twice (10 ms each, as in one process): in a process of its own nothing else
# lives on its step grid (the other groups' timers follow the clock on their own), and each
# wake-up of a Python process costs ~0.2-0.4 ms of CPU at rest. Only the bytes' timing within
# those 20 ms changes: the firmware writes ODOM + IMU once per ODOM period anyway.
SOURCE_STEPS_PER_WAKE = 2
# ... and once per 40 ms while the simulated MCU is idle (no command, wheels still): the
# firmware's frames then come two at a time every 40 ms and a first command from rest waits
# up to 40 ms (instead of 10) for the firmware model to take it. Once it is moving, 20 ms.
SOURCE_IDLE_STEPS_PER_WAKE = 4
STDIN_FD = 0  # --parent-pipe: the supervisor holds the other end of stdin
STDIN_READ_BYTES = 4096  # nothing is ever written there: one read sees the end


GROUP_LISTEN = "tcp/127.0.0.1:0"  # a group's own endpoint: loopback, a port the system picks


def group_health_topic(group: str) -> Topic[HealthReport]:
    return Topic(f"{GROUP_HEALTH_PREFIX}{group}", HealthReport)


def group_settings(profile: str | None, overrides: dict[str, Any], connect: str) -> Settings:
    """The profile with ``overrides`` and the bus as a Zenoh peer that meets the others at the
    router ``connect``: it listens on a free loopback port, and the router's gossip tells the
    other groups where, so messages between two groups go straight from one to the other
    (one hop, not two through the router)."""
    bus = {"transport": "zenoh", "zenoh": {"mode": "peer", "listen": [GROUP_LISTEN], "connect": [connect]}}
    merged = dict(overrides)
    merged["bus"] = {**merged.get("bus", {}), **bus}
    return load_profile(profile, merged)


def group_specs(mode: str, nodes: list[str]) -> list[NodeSpec]:
    """The specs of ``nodes`` as ``mode``'s profile has them (nodes it lacks: not critical).
    Only these nodes' modules are imported."""
    if mode not in PROFILES:
        raise ConfigError(f"unknown mode {mode!r}; modes: {', '.join(sorted(PROFILES))}")
    critical = dict(PROFILES[mode])
    return [NodeSpec(n, node_class(n), critical.get(n, False)) for n in nodes]


def make_clock(mode: str, start: float, board: str = "") -> Clock:
    if mode == "source":
        return SimClock(
            start, steps_per_wake=SOURCE_STEPS_PER_WAKE, idle_steps_per_wake=SOURCE_IDLE_STEPS_PER_WAKE
        )
    if mode == "follow":
        return FollowerClock(start, ClockBoard(board) if board else None)
    return WallClock()


def write_board(ctx: NodeContext, board: ClockBoard) -> None:
    """The simulator's group: put the time on the shared page at every physics step."""
    clock, speed = ctx.clock, float(ctx.settings.sim.speed or 0.0)

    def on_step(_dt: float) -> None:
        board.write(clock.now(), time.monotonic(), speed)

    ctx.resources[SIM_STEP_HOOKS].append(on_step)


async def keep_port_link(ctx: NodeContext, link: Path) -> None:
    """Keep ``link`` pointing at the simulated MCU's pty (the simulator's group)."""
    current = ""
    while True:
        target = ctx.resources.get(PORT_RESOURCE) or ""
        if target and target != current:
            tmp = link.with_name(link.name + ".new")
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()
            os.symlink(target, tmp)
            os.replace(tmp, link)
            current = target
        await ctx.clock.sleep(PORT_WATCH_S)


def watch_parent(launcher: Launcher) -> None:
    """Stop the group when the supervisor that started it is gone (even ``kill -9``): it holds
    the other end of our stdin, which reads end-of-file then."""
    loop = asyncio.get_running_loop()

    def on_readable() -> None:
        try:
            data = os.read(STDIN_FD, STDIN_READ_BYTES)
        except OSError:
            data = b""
        if not data:
            loop.remove_reader(STDIN_FD)
            launcher.request_stop()

    loop.add_reader(STDIN_FD, on_readable)


async def run_group(
    ctx: NodeContext, specs: list[NodeSpec], export_port: str = "", parent_pipe: bool = False
) -> Launcher:
    """Run the group's nodes until a signal (or, with ``parent_pipe``, the supervisor's end);
    the simulator's group also publishes ``/clock``."""
    clock = ctx.clock
    if isinstance(clock, FollowerClock):
        return await _run_following(ctx, specs, clock, parent_pipe)
    tasks: list[Any] = []

    async def after_start(launcher: Launcher) -> None:
        if parent_pipe:
            watch_parent(launcher)
        if isinstance(clock, SimClock):
            tasks.append(publish_clock(ctx.bus, clock, ctx.settings.sim.speed))
        if export_port:
            tasks.append(asyncio.get_running_loop().create_task(keep_port_link(ctx, Path(export_port))))

    try:
        return await run_launcher(ctx, specs, after_start=after_start)
    finally:
        for task in tasks:
            task.cancel()


async def _run_following(
    ctx: NodeContext, specs: list[NodeSpec], clock: FollowerClock, parent_pipe: bool
) -> Launcher:
    sub = None if clock.reads_board else clock.attach(ctx.bus)
    launcher = Launcher(ctx, specs)
    launcher.install_signal_handlers()
    if parent_pipe:
        watch_parent(launcher)
    try:
        await launcher.start()
        await launcher._stop_event.wait()
        await launcher.stop()
    finally:
        if sub is not None:
            sub.close()
        ctx.bus.transport.close()
    return launcher


def build_context(args: argparse.Namespace) -> tuple[NodeContext, list[NodeSpec]]:
    overrides = json.loads(args.overrides) if args.overrides else {}
    settings = group_settings(args.profile, overrides, args.connect)
    specs = group_specs(args.mode, [n for n in args.nodes.split(",") if n])
    clock = make_clock(args.clock, args.start_time, args.clock_board)
    ctx = NodeContext(Bus(clock, make_transport(settings)), clock, settings)
    ctx.resources[SIM_STEP_HOOKS] = []
    if args.clock == "source" and args.clock_board:
        write_board(ctx, ClockBoard(args.clock_board))
    ctx.resources[HEALTH_TOPIC] = group_health_topic(args.group)
    if args.mcu_port:
        ctx.resources[PORT_RESOURCE] = args.mcu_port
    if args.export_port:  # the motion group's bridge reads the simulator's pty
        ctx.resources[PORT_READ_ELSEWHERE] = True
    return ctx, specs


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="python -m sage_robot.app.group_main",
                                description=(__doc__ or "").splitlines()[0])
    p.add_argument("--group", required=True, help="the group's name (processes.groups)")
    p.add_argument("--mode", required=True, help="the profile's mode (sim, tour, slam, sim_slam)")
    p.add_argument("--nodes", required=True, help="the group's nodes, comma-separated")
    p.add_argument("--connect", required=True, help="the supervisor's Zenoh router endpoint")
    p.add_argument("--profile", help="the profile YAML (default: the shipped simulated robot)")
    p.add_argument("--overrides", default="", help="settings overrides as a JSON object")
    p.add_argument("--clock", default="wall", choices=CLOCK_MODES)
    p.add_argument("--start-time", type=float, default=0.0, help="simulated start time (s)")
    p.add_argument("--clock-board", default="",
                   help="the shared page of the simulator's time (source: written; follow: read)")
    p.add_argument("--export-port", default="", help="keep a link to the simulated MCU's pty here")
    p.add_argument("--mcu-port", default="", help="the serial bridge opens this port")
    p.add_argument("--nice", type=int, default=0, help="lower this process's CPU priority by this much")
    p.add_argument("--realtime", type=int, default=0,
                   help="run this process at this real-time priority (SCHED_FIFO 1-99; 0: normal)")
    p.add_argument("--parent-pipe", action="store_true",
                   help="stop when stdin reaches its end (the supervisor is gone)")
    return p.parse_args(argv)


def raise_zenoh_threads(group: str, priority: int) -> None:
    """Zenoh's network threads (started with the bus's session) at ``processes.zenoh_realtime``,
    and those it starts later too: a pool thread started from a thread at the normal priority
    (a Python thread calling into Zenoh) does not inherit it, so a watcher thread raises them
    every ``ZENOH_RERAISE_S`` (wall clock) for the life of the process."""
    if not priority:
        return
    _raised, refused = raise_threads(priority, ZENOH_THREADS)
    if refused:  # the robot runs on; messages may wait for a time slice
        print(f"sage group {group}: Zenoh threads: {refused}; they run at the normal priority",
              file=sys.stderr)
        return

    def watch() -> None:
        while True:
            time.sleep(ZENOH_RERAISE_S)
            if raise_threads(priority, ZENOH_THREADS)[1]:  # refused now: nothing more to do
                return

    threading.Thread(target=watch, name="sage-zenoh-prio", daemon=True).start()


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if args.nice:  # first, so every thread the process starts has it
        os.nice(args.nice)
    if args.realtime:
        refused = set_fifo(args.realtime)
        if refused:  # the robot runs on; the operator learns why its motion path is not real-time
            print(f"sage group {args.group}: {refused}; running at the normal priority", file=sys.stderr)
    try:
        ctx, specs = build_context(args)
        raise_zenoh_threads(args.group, ctx.settings.processes.zenoh_realtime)
        event_loop.run(run_group(ctx, specs, args.export_port, args.parent_pipe), fast=True)
    except (SageError, json.JSONDecodeError) as exc:
        print(f"sage group {args.group}: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
