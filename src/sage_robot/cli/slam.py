"""`sage slam`: build a map.

- ``sage slam [--out DIR] [--name NAME] [--imu]``: the simulator in SLAM mode (profile "sim_slam":
  world, firmware model, serial bridge, web, Foxglove, heartbeat, battery watchdog, ``slam``).
  Drive the robot from the web page; the map grows on ``/map``. The session is saved to
  ``DIR/NAME.{yaml,pgm,graph.npz,trajectory.txt}`` when it stops (Ctrl-C or ``--duration``);
  the ``/slam/save`` bus service saves on demand while it runs.
- ``sage slam replay LOG [--out DIR] [--name NAME] [--limit N]``: run the same SLAM over a
  CARMEN log (FLASER / ROBOTLASER1 / ODOM, optionally gzipped) with a progress bar and write
  map, pose graph and trajectory; ends with a quality report (loops closed, residuals of the
  optimised pose graph per edge kind), also in ``--json`` under ``"quality"``.
- ``sage slam tour NAME [--out DIR]``: make a saved map the tour map: writes
  ``DIR/NAME.profile.yaml`` (and ``NAME.waypoints.yaml``); ``sage sim --profile …`` tours it.
- ``sage slam save NAME [--url URL]``: save the running session (``sage slam`` or ``sage up
  --mode slam``) as NAME through its web server (``POST /api/slam/save``, like ``sage status``
  reaches a robot): logs in as the operator with ``SAGE_OPERATOR_PASSWORD`` or the stored
  generated password, and the node writes into its own output directory.
- ``sage slam save NAME --from OLD.graph.npz [--resolution R] [--out DIR]``: write a saved
  session again under another name (map re-rendered from the pose graph).
- On the real robot: ``sage up --mode slam`` (the "slam" profile includes the node); with
  ``--imu`` (both commands) the bridge publishes the gyro and the odometry turns with it.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import urllib.error
import urllib.request
from http.cookiejar import CookieJar
from pathlib import Path
from typing import Any

DEFAULT_NAME = "slam_map"
DEFAULT_OUT = "maps"  # ./maps unless the profile's slam.out_dir says otherwise
HTTP_TIMEOUT_S = 130.0  # the server allows the save 120 s


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser("slam", help="build a map: in the simulator, or offline from a CARMEN log")
    p.add_argument("--out", help="directory for the saved map (default: slam.out_dir, else ./maps)")
    p.add_argument("--name", default=DEFAULT_NAME, help="map name (files NAME.yaml, NAME.pgm, ...)")
    p.add_argument("--speed", type=float, help="simulator real-time factor")
    p.add_argument("--duration", type=float, help="stop (and save) after this many simulated seconds")
    p.add_argument("--headless", action="store_true", help="no web server")
    p.add_argument(
        "--imu",
        action="store_true",
        help="publish /imu/data: the odometry turns with the gyro (docs/slam.md)",
    )
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
    v = ssub.add_parser("save", help="save the running session as NAME, or a saved one again (--from)")
    v.add_argument("name", help="map name (files NAME.yaml, NAME.pgm, ...)")
    v.add_argument("--url", help="robot web address (default http(s)://127.0.0.1:<web.port>, per web.tls)")
    v.add_argument("--from", dest="source", help="instead: write a saved NAME.graph.npz again")
    v.add_argument("--out", help="with --from: output directory (default: ./maps)")
    v.add_argument("--resolution", type=float, default=0.05, help="with --from: map cell size (m)")
    v.set_defaults(func=run_save)
    t = ssub.add_parser("tour", help="make a saved map the tour map (writes NAME.profile.yaml)")
    t.add_argument("name", help="the saved map's name (DIR/NAME.yaml)")
    t.add_argument("--out", help="the maps' directory (default: slam.out_dir, else ./maps)")
    t.set_defaults(func=run_tour)


def run_mapping(args: argparse.Namespace) -> int:
    from sage_robot.app.runtime import run_launcher, specs_for
    from sage_robot.core.config import load_profile
    from sage_robot.core.errors import ConfigError
    from sage_robot.nav.slam.node import SAVED_RESOURCE
    from sage_robot.nav.slam.store import check_name

    check_name(args.name)
    if args.duration is not None and args.duration <= 0:
        raise ConfigError(f"--duration must be > 0 s, got {args.duration}")
    overrides: dict[str, Any] = {"sim": {"speed": args.speed}} if args.speed else {}
    if args.imu:
        overrides["mcu"] = {"imu_enabled": True}
    settings = load_profile(args.profile, overrides or None)
    ctx = mapping_context(settings, args.out, args.name)
    specs = [s for s in specs_for("sim_slam") if not (args.headless and s.name == "web")]
    print(f"SAGE SLAM in simulation: {', '.join(s.name for s in specs)}; Ctrl-C to stop and save")
    asyncio.run(run_launcher(ctx, specs, until=args.duration))
    saved = ctx.resources.get(SAVED_RESOURCE)
    if saved:
        print(f"map saved: {saved['yaml']} (pose graph {saved['graph']})")
        return 0
    print("no map saved (no scans were mapped)")
    return 1


def mapping_context(settings: Any, out: str | None, name: str) -> Any:
    """The simulated robot's context for mapping: maps go to ``out`` (else ``slam.out_dir``,
    else ./maps), the session is saved as ``name`` on exit, and the map frame is the
    building's (the first scan is mapped at the robot's start pose, ``nav.initial_place``),
    so places added on the new map stand where they are in the simulated building."""
    from sage_robot.app.runtime import make_context
    from sage_robot.core.paths import waypoints_yaml
    from sage_robot.core.places import Places, load_places
    from sage_robot.nav.slam.node import AUTOSAVE_RESOURCE, INITIAL_POSE_RESOURCE, OUT_DIR_RESOURCE
    from sage_robot.sim.setup import pose_resolver

    ctx = make_context(settings, simulated=True)
    ctx.resources[OUT_DIR_RESOURCE] = str(Path(out or settings.slam.out_dir or DEFAULT_OUT).resolve())
    ctx.resources[AUTOSAVE_RESOURCE] = name
    wp = waypoints_yaml(settings)
    places = load_places(wp) if wp.exists() else Places([], str(wp))
    start = pose_resolver(places)(settings.nav.initial_place, "nav.initial_place")
    ctx.resources[INITIAL_POSE_RESOURCE] = start
    return ctx


def run_tour(args: argparse.Namespace) -> int:
    from sage_robot.core.config import load_profile
    from sage_robot.nav.slam.tour import make_tour_profile

    settings = load_profile(args.profile)
    tour = make_tour_profile(settings, args.out or settings.slam.out_dir or DEFAULT_OUT, args.name)
    print(f"tour map: {tour.map} ({tour.places} places in {tour.waypoints})")
    print(f"profile: {tour.profile}\ntour it: sage sim --profile {tour.profile}")
    return 0


def run_save(args: argparse.Namespace) -> int:
    from sage_robot.core.errors import ConfigError
    from sage_robot.nav.slam.store import build_map, check_name, load_session, save_session

    check_name(args.name)
    if args.source is None:
        if args.out is not None:
            raise ConfigError("--out goes with --from: a running session saves into its own directory")
        return save_running(args)
    if args.url is not None:
        raise ConfigError("--url and --from exclude each other: --from re-writes a saved session here")
    if args.resolution <= 0:
        raise ConfigError(f"--resolution must be > 0 m, got {args.resolution}")
    slam = load_session(args.source)
    paths = save_session(slam, args.out or DEFAULT_OUT, args.name, build_map(slam, args.resolution))
    print(f"map: {paths['yaml']}\npose graph: {paths['graph']}")
    return 0


def save_running(args: argparse.Namespace) -> int:
    """Ask the running robot's web server to save its SLAM session as ``args.name``."""
    from sage_robot.core.config import load_profile

    settings = load_profile(args.profile)
    from sage_robot.web.tls import client_context, local_url

    base = (args.url or local_url(settings.web)).rstrip("/")
    handlers: list[Any] = [urllib.request.HTTPCookieProcessor(CookieJar())]
    if base.startswith("https:"):  # the robot's own (maybe self-signed) certificate
        handlers.append(urllib.request.HTTPSHandler(context=client_context(settings.web)))
    opener = urllib.request.build_opener(*handlers)
    _post(opener, base, "/api/login", {"password": client_password(settings)})
    reply = _post(opener, base, "/api/slam/save", {"name": args.name})
    print(f"map: {reply['yaml']}\npose graph: {reply['graph']}\ntrajectory: {reply['trajectory']}")
    return 0


def client_password(settings: Any) -> str:
    """The operator password as the web server reads it, without generating a new one."""
    from sage_robot.core.config import read_secret
    from sage_robot.core.errors import SageError
    from sage_robot.core.paths import state_dir
    from sage_robot.web.auth import PASSWORD_ENV, PASSWORD_FILE

    secret = read_secret(PASSWORD_ENV, settings.secrets_file or None)
    if secret is not None:
        return secret.get_secret_value()
    path = state_dir() / PASSWORD_FILE
    text = path.read_text(encoding="utf-8").strip() if path.exists() else ""
    if not text:
        raise SageError(f"no operator password: set {PASSWORD_ENV} (or run this where {path} exists)")
    return text


def _post(opener: Any, base: str, route: str, body: dict[str, Any]) -> dict[str, Any]:
    """POST JSON; one clear SageError for an unreachable server or a refusal."""
    from sage_robot.core.errors import SageError

    req = urllib.request.Request(
        base + route, json.dumps(body).encode(), {"Content-Type": "application/json"}, method="POST"
    )
    try:
        with opener.open(req, timeout=HTTP_TIMEOUT_S) as resp:
            return json.load(resp)  # type: ignore[no-any-return]
    except urllib.error.HTTPError as exc:
        try:
            detail = json.load(exc).get("error", exc.reason)
        except ValueError:
            detail = exc.reason
        raise SageError(f"{base}{route}: {exc.code} {detail}") from None
    except (urllib.error.URLError, OSError) as exc:
        hint = "is `sage slam` or `sage up --mode slam` running?"
        raise SageError(f"no robot answers at {base} ({exc}); {hint}") from None


def run_replay(args: argparse.Namespace) -> int:
    from sage_robot.core.errors import ConfigError
    from sage_robot.nav.slam.carmen import read_log
    from sage_robot.nav.slam.replay import format_report, quality_report, replay_log
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
    quality = quality_report(slam)
    summary = {
        "log": str(args.log),
        "scans": len(result.log.scans),
        "keyframes": len(slam.keyframes),
        "loop_closures": slam.loop_closures,
        "seconds": round(result.seconds, 2),
        "realtime_factor": round(result.realtime_factor, 2),
        **paths,
        "quality": quality,
    }
    if args.json:
        print(json.dumps(summary))
    else:
        print(
            f"{summary['scans']} scans, {summary['keyframes']} keyframes, {summary['loop_closures']} loop "
            f"closures in {summary['seconds']} s ({summary['realtime_factor']}x real time)"
        )
        print(f"map: {paths['yaml']}\ntrajectory: {paths['trajectory']}\npose graph: {paths['graph']}")
        print(format_report(quality))
    return 0
