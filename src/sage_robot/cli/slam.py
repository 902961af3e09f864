"""`sage slam`: build a map.

- ``sage slam [--out DIR] [--name NAME]``: the simulator in SLAM mode (profile "sim_slam":
  the sim nodes without localization, navigator and map server, plus the ``slam`` node).
  Drive the robot from the web page; the map grows on ``/map``. The session is saved to
  ``DIR/NAME.{yaml,pgm,graph.npz,trajectory.txt}`` when it stops (Ctrl-C or ``--duration``);
  the ``/slam/save`` bus service saves on demand while it runs.
- ``sage slam replay LOG [--out DIR] [--name NAME] [--limit N]``: run the same SLAM over a
  CARMEN log (FLASER / ROBOTLASER1 / ODOM, optionally gzipped) with a progress bar and write
  map, pose graph and trajectory.
- ``sage slam save NAME --from OLD.graph.npz [--resolution R]``: write a saved session again
  under another name (map re-rendered from the pose graph, e.g. at another resolution). A
  running session is saved by the ``/slam/save`` service or on exit: the bus is in-process,
  so another ``sage`` process cannot reach it.
- On the real robot: ``sage up --mode slam`` (the "slam" profile includes the node).
"""

from __future__ import annotations

import argparse
import asyncio
import json
from pathlib import Path

DEFAULT_NAME = "slam_map"


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser("slam", help="build a map: in the simulator, or offline from a CARMEN log")
    p.add_argument("--out", default="maps", help="directory for the saved map (default: ./maps)")
    p.add_argument("--name", default=DEFAULT_NAME, help="map name (files NAME.yaml, NAME.pgm, ...)")
    p.add_argument("--speed", type=float, help="simulator real-time factor")
    p.add_argument("--duration", type=float, help="stop (and save) after this many simulated seconds")
    p.add_argument("--headless", action="store_true", help="no web server")
    p.set_defaults(func=run_mapping, help_parser=p)
    ssub = p.add_subparsers(dest="slam_command", metavar="SUBCOMMAND")
    r = ssub.add_parser("replay", help="run SLAM over a CARMEN log and write map + trajectory")
    r.add_argument("log", help="CARMEN log (.clf, .log, .gz)")
    r.add_argument("--out", default="maps", help="output directory (default: ./maps)")
    r.add_argument("--name", help="map name (default: the log's name)")
    r.add_argument("--limit", type=int, help="only the first N scans")
    r.add_argument("--resolution", type=float, default=0.05, help="map cell size (m)")
    r.add_argument("--json", action="store_true", help="print a JSON summary")
    r.set_defaults(func=run_replay)
    v = ssub.add_parser("save", help="write a saved session again as NAME (e.g. another resolution)")
    v.add_argument("name", help="new map name")
    v.add_argument("--from", dest="source", required=True, help="a saved NAME.graph.npz or NAME.yaml")
    v.add_argument("--out", default="maps", help="output directory (default: ./maps)")
    v.add_argument("--resolution", type=float, default=0.05, help="map cell size (m)")
    v.set_defaults(func=run_save)


def run_mapping(args: argparse.Namespace) -> int:
    from sage_robot.app.runtime import make_context, run_launcher, specs_for
    from sage_robot.core.config import load_profile
    from sage_robot.core.errors import ConfigError
    from sage_robot.nav.slam.node import AUTOSAVE_RESOURCE, OUT_DIR_RESOURCE, SAVED_RESOURCE
    from sage_robot.nav.slam.store import check_name

    check_name(args.name)
    if args.duration is not None and args.duration <= 0:
        raise ConfigError(f"--duration must be > 0 s, got {args.duration}")
    overrides = {"sim": {"speed": args.speed}} if args.speed else None
    settings = load_profile(args.profile, overrides)
    ctx = make_context(settings, simulated=True)
    ctx.resources[OUT_DIR_RESOURCE] = str(Path(args.out).resolve())
    ctx.resources[AUTOSAVE_RESOURCE] = args.name
    specs = [s for s in specs_for("sim_slam") if not (args.headless and s.name == "web")]
    print(f"SAGE SLAM in simulation: {', '.join(s.name for s in specs)}; Ctrl-C to stop and save")
    asyncio.run(run_launcher(ctx, specs, until=args.duration))
    saved = ctx.resources.get(SAVED_RESOURCE)
    if saved:
        print(f"map saved: {saved['yaml']} (pose graph {saved['graph']})")
        return 0
    print("no map saved (no scans were mapped)")
    return 1


def run_save(args: argparse.Namespace) -> int:
    from sage_robot.core.errors import ConfigError
    from sage_robot.nav.slam.store import build_map, check_name, load_session, save_session

    check_name(args.name)
    if args.resolution <= 0:
        raise ConfigError(f"--resolution must be > 0 m, got {args.resolution}")
    slam = load_session(args.source)
    paths = save_session(slam, args.out, args.name, build_map(slam, args.resolution))
    print(f"map: {paths['yaml']}\npose graph: {paths['graph']}")
    return 0


def run_replay(args: argparse.Namespace) -> int:
    from sage_robot.core.errors import ConfigError
    from sage_robot.nav.slam.carmen import read_log
    from sage_robot.nav.slam.replay import replay_log
    from sage_robot.nav.slam.store import build_map, save_session

    if args.limit is not None and args.limit < 1:
        raise ConfigError(f"--limit must be >= 1, got {args.limit}")
    if args.resolution <= 0:
        raise ConfigError(f"--resolution must be > 0 m, got {args.resolution}")
    log = read_log(args.log, progress=not args.json)
    result = replay_log(log, limit=args.limit, progress=not args.json)
    slam = result.slam
    name = args.name or Path(args.log).name.split(".")[0]
    paths = save_session(slam, args.out, name, build_map(slam, args.resolution))
    summary = {
        "log": str(args.log),
        "scans": len(result.log.scans),
        "keyframes": len(slam.keyframes),
        "loop_closures": slam.loop_closures,
        "seconds": round(result.seconds, 2),
        "realtime_factor": round(result.realtime_factor, 2),
        **paths,
    }
    if args.json:
        print(json.dumps(summary))
    else:
        print(
            f"{summary['scans']} scans, {summary['keyframes']} keyframes, {summary['loop_closures']} loop "
            f"closures in {summary['seconds']} s ({summary['realtime_factor']}x real time)"
        )
        print(f"map: {paths['yaml']}\ntrajectory: {paths['trajectory']}\npose graph: {paths['graph']}")
    return 0
