"""`sage record`, `sage replay`, `sage status`, `sage install-service`."""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import shutil
import sys
import urllib.error
import urllib.request
from pathlib import Path
from typing import Any

from sage_robot.core.errors import SageError

ZENOH_PROBE_S = 0.5  # `sage status` asks Zenoh this long first when the profile's bus is local

SERVICE_TEMPLATE = """[Unit]
Description=SAGE tour robot ({mode})
After=network-online.target
Wants=network-online.target

[Service]
Type=simple
User={user}
WorkingDirectory={workdir}
Environment=PYTHONUNBUFFERED=1
# the motion process may take its real-time priority (processes.realtime, --processes)
LimitRTPRIO={rtprio}
ExecStart={sage} {profile_arg}up --mode {mode}{processes}
Restart=on-failure
RestartSec=5
KillSignal=SIGINT
TimeoutStopSec=15

[Install]
WantedBy=multi-user.target
"""


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser("record", help="run the robot (simulated by default) and record topics to MCAP")
    p.add_argument("out", help="output .mcap file")
    p.add_argument("--topics", nargs="+", help="topics to record (default: the profile's ops.record_topics)")
    p.add_argument("--mode", default="sim", help="profile to run while recording (sim, tour, slam)")
    p.add_argument("--duration", type=float, help="stop after this many seconds (of the run's clock)")
    p.add_argument("--fast", action="store_true", help="simulation as fast as possible")
    p.add_argument(
        "--attach",
        action="store_true",
        help="record a robot that is already running (bus.transport: zenoh) instead of starting one",
    )
    p.add_argument("--connect", action="append", help="with --attach: robot endpoint (repeatable)")
    p.set_defaults(func=run_record)

    p = sub.add_parser("replay", help="feed an MCAP recording back onto the bus (with web and Foxglove)")
    p.add_argument("file", help=".mcap file made by `sage record`")
    p.add_argument("--speed", type=float, default=1.0, help="playback speed factor")
    p.add_argument("--nodes", nargs="*", default=["foxglove"], help="nodes to run beside the replay")
    p.set_defaults(func=run_replay)

    p = sub.add_parser(
        "status", help="health of every node of a running robot (over Zenoh, else from its web server)"
    )
    p.add_argument(
        "--url",
        help="ask this web address only (default: Zenoh first, then http(s)://127.0.0.1:<web.port>)",
    )
    p.add_argument("--json", action="store_true", help="print the raw JSON")
    p.set_defaults(func=run_status)

    p = sub.add_parser("profile-from-urdf", help="print profile lines (lidar pose, track) from a URDF/xacro")
    p.add_argument("file", help="the robot's .urdf or .urdf.xacro")
    p.add_argument("--lidar-link", default="lidar_link")
    p.add_argument("--base-link", default="base_link")
    p.set_defaults(func=run_profile_from_urdf)

    p = sub.add_parser("install-service", help="write a systemd unit so the robot starts at boot")
    p.add_argument("--mode", default="tour", choices=["tour", "slam"])
    p.add_argument("--processes", action="store_true",
                   help="run the process groups (crash isolation; motion at its real-time priority)")
    p.add_argument("--out", default="/etc/systemd/system/sage.service", help="where to write the unit")
    p.add_argument("--user", default=os.environ.get("SUDO_USER") or os.environ.get("USER") or "root")
    p.set_defaults(func=run_install_service)


def run_record(args: argparse.Namespace) -> int:
    from sage_robot.app.recording.nodes import RECORD_PATH, RECORD_TOPICS
    from sage_robot.app.runtime import make_context, run_launcher, specs_for
    from sage_robot.core.config import load_profile

    if args.attach:
        return record_attached(args)
    over = {"sim": {"speed": None}} if args.fast else None
    settings = load_profile(args.profile, over)
    ctx = make_context(settings, simulated=args.mode.startswith("sim"))
    ctx.resources[RECORD_PATH] = Path(args.out)
    if args.topics:
        ctx.resources[RECORD_TOPICS] = args.topics
    launcher = asyncio.run(run_launcher(ctx, specs_for(args.mode, ["recorder"]), until=args.duration))
    counts = launcher.health_report().get("recorder", {}).get("stats", {})
    print(f"wrote {args.out}: {json.dumps(counts)}")
    return 0


def record_attached(args: argparse.Namespace) -> int:
    """`sage record OUT --attach`: the recorder node on a bus that only listens to the running
    robot over Zenoh, for ``--duration`` wall seconds or until Ctrl-C."""
    from sage_robot.app.launcher import NodeSpec
    from sage_robot.app.recording.nodes import RECORD_PATH, RECORD_TOPICS
    from sage_robot.app.registry import node_class
    from sage_robot.app.runtime import run_launcher
    from sage_robot.core.bus import Bus
    from sage_robot.core.clock import WallClock
    from sage_robot.core.config import load_profile
    from sage_robot.core.node import NodeContext

    try:
        from sage_robot.core.transport.remote import RemoteRobot, ZenohListener
    except ImportError as exc:
        raise SageError(f"--attach needs the zenoh extra (pip install 'sage-robot[zenoh]'): {exc}") from None
    if args.duration is not None and args.duration <= 0:
        raise SageError(f"--duration must be > 0 s, got {args.duration:g}")
    settings = load_profile(args.profile)
    topics = list(args.topics or settings.ops.record_topics)
    robot = RemoteRobot(settings.bus, args.connect)
    try:
        robot.require_connected()
        transport = ZenohListener(robot, topics)
    except SageError:
        robot.close()
        raise
    clock = WallClock()
    ctx = NodeContext(Bus(clock, transport), clock, settings)
    ctx.resources[RECORD_PATH] = Path(args.out)
    ctx.resources[RECORD_TOPICS] = topics

    async def stop_later(launcher: Any) -> None:
        if args.duration is not None:
            asyncio.get_running_loop().call_later(args.duration, launcher.request_stop)

    specs = [NodeSpec("recorder", node_class("recorder"))]
    launcher = asyncio.run(run_launcher(ctx, specs, after_start=stop_later))
    counts = launcher.health_report().get("recorder", {}).get("stats", {})
    print(f"wrote {args.out}: {json.dumps(counts)}")
    return 0


def run_replay(args: argparse.Namespace) -> int:
    from sage_robot.app.launcher import NodeSpec
    from sage_robot.app.recording.nodes import REPLAY_PATH, REPLAY_SPEED
    from sage_robot.app.registry import node_class
    from sage_robot.app.runtime import make_context, run_launcher
    from sage_robot.core.config import load_profile

    if not Path(args.file).exists():
        raise SageError(f"{args.file}: recording not found")
    ctx = make_context(load_profile(args.profile), simulated=False)
    ctx.resources[REPLAY_PATH] = args.file
    ctx.resources[REPLAY_SPEED] = float(args.speed)
    specs = [NodeSpec("replay", node_class("replay"), restart=False)]
    specs += [NodeSpec(n, node_class(n)) for n in args.nodes]
    asyncio.run(run_launcher(ctx, specs))
    return 0


def run_status(args: argparse.Namespace) -> int:
    from sage_robot.core.config import load_profile

    settings = load_profile(args.profile)
    report = None if args.url else health_over_zenoh(settings)
    if report is None:
        report = _health_over_web(settings, args.url)
    if args.json:
        print(json.dumps(report, indent=2))
        return 0
    nodes = report.get("nodes", report)
    print(f"{'node':<18} {'state':<9} {'restarts':>8}  last error")
    for name, h in nodes.items():
        print(f"{name:<18} {h.get('state', '?'):<9} {h.get('restarts', 0):>8}  {h.get('last_error', '')}")
    bad = [n for n, h in nodes.items() if h.get("state") != "running"]
    return 1 if bad else 0


def health_over_zenoh(settings: Any) -> dict[str, Any] | None:
    """The robot's ``/sage/health`` asked over Zenoh (no robot started here), shaped like the
    web's ``/api/health``; None when Zenoh is not installed or no robot answers in time."""
    import dataclasses

    from sage_robot.core import topics

    try:
        from sage_robot.core.transport.remote import RemoteRobot
    except ImportError:
        return None
    bus = settings.bus
    timeout = bus.zenoh.open_timeout_s if bus.transport == "zenoh" else ZENOH_PROBE_S
    try:
        with RemoteRobot(bus, timeout_s=timeout) as robot:
            report = robot.last(topics.HEALTH) if robot.wait_connected() else None
    except SageError:
        return None
    if report is None:
        return None
    return {
        "nodes": {h.name: dataclasses.asdict(h) for h in report.nodes},
        "time": report.stamp,
        "robot": settings.robot.name,
        "via": "zenoh",
    }


def _health_over_web(settings: Any, url_arg: str | None) -> Any:
    from sage_robot.web.tls import client_context, local_url

    web = settings.web
    url = (url_arg or local_url(web)).rstrip("/") + "/api/health"
    try:
        context = client_context(web) if url.startswith("https:") else None
        with urllib.request.urlopen(url, timeout=5, context=context) as resp:
            return json.load(resp)
    except (urllib.error.URLError, OSError) as exc:
        raise SageError(f"no robot answers at {url} ({exc}); is `sage sim` or `sage up` running?") from None


def run_install_service(args: argparse.Namespace) -> int:
    sage = shutil.which("sage") or str(Path(sys.executable).with_name("sage"))
    profile_arg = f"--profile {Path(args.profile).resolve()} " if args.profile else ""
    from sage_robot.core.config import load_profile

    procs = load_profile(args.profile, {}).processes
    rtprio = max([*procs.realtime.values(), procs.zenoh_realtime])
    unit = SERVICE_TEMPLATE.format(
        mode=args.mode, user=args.user, workdir=Path.cwd(), sage=sage, profile_arg=profile_arg, rtprio=rtprio,
        processes=" --processes" if args.processes else "",
    )
    out = Path(args.out)
    try:
        out.write_text(unit)
    except PermissionError:
        raise SageError(f"cannot write {out}: run with sudo, or choose --out") from None
    print(f"wrote {out}")
    print("enable it with: sudo systemctl daemon-reload && sudo systemctl enable --now sage")
    print("the robot starts at boot from its dock, where its initial pose is (nav.initial_place)")
    return 0


def run_profile_from_urdf(args: argparse.Namespace) -> int:
    from sage_robot.app.urdf import read_geometry

    geo = read_geometry(args.file, lidar_link=args.lidar_link, base_link=args.base_link)
    print(f"# from {args.file}: paste into your profile")
    print(geo.profile_yaml(), end="")
    return 0
