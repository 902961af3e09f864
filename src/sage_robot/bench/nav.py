"""Navigation end to end: the simulated robot drives between places with people and clutter.

Runs the simulator's world node (people, lidar, collisions) with the map_server,
localization and navigator nodes on the simulated clock, and sends ``navigate_to`` goals:
every ordered pair of places (an Eulerian circuit, so each leg starts where the last
ended) or N random legs. Reports success rate, collisions, failures with reasons,
time and path length against the shortest plan, time spent waiting for people, how often
the robot asked them to step aside, and localization RMSE against truth.

Any map works: ``--places auto N`` chooses N well-separated places the robot can reach
(``nav_places``) when the map has no waypoints file, and the ``--clutter`` boxes are placed
only where a path the robot fits through remains between all places (``boxes_placed``,
``paths_remain`` in the result).

Wheel odometry here is derived from the simulated body with a scale error
(``ODOM_SCALE_ERROR``): the pseudo-terminal MCU link runs in wall time and cannot keep pace
with a faster-than-real-time clock.
"""

from __future__ import annotations

import argparse
import asyncio
import itertools
import json
import math
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from sage_robot.core.errors import SageError

ODOM_SCALE_ERROR = 0.01  # wheel odometry reads 1 % long
CLUTTER_HEIGHT_M = 1.0  # unmapped boxes as tall as this (the lidar sees them)
ARRIVED_M = 1.0  # a leg succeeds when the navigator says so and the robot truly stands this close
# to the goal (the navigator may settle a little short of a spot people stand on)
SAID_ARRIVED = "the navigator reported arrival"  # a failure reason: it did, too far from the goal
PLACES_STREAM = 1  # --places auto draws from the generator seeded (seed, this): legs keep theirs
# Events in which the robot asks people to step aside ("excuse me"): the navigator's
# blocked_by_people (its message is "excuse me, may I pass?"), or any kind that says so.
EXCUSE_ME_KINDS = frozenset({"blocked_by_people", "excuse_me"})
LEG_TIMEOUT_S = 300.0  # simulated seconds per leg before it counts as failed
SAMPLE_PERIOD_S = 0.2  # localization error sampling (simulated s)
NEAR_PERSON_M = 5.0  # a failed leg lists the simulated people this close to the robot
PEOPLE_WAIT_S = 60.0  # the simulator's visitors who walk up to the robot stay 30-60 s
# At most one simulated person per this much walkable floor (m^2): Fruin's level of service A
# for walkways (people walk at their own speed and pass freely). The TurtleBot sandbox (about
# 20 m^2, floor at most 1.45 m wide) holds 5; the building maps hold the 10 asked for.
FLOOR_PER_PERSON_M2 = 3.3


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--map", default="", help="map YAML (default: the shipped building)")
    p.add_argument("--waypoints", default="", help="waypoints YAML, own/Nav2 (default: beside the map)")
    p.add_argument("--places", nargs=2, default=None, metavar=("auto", "N"),
                   help="'auto N': N well-separated reachable places chosen from the map (seeded; "
                        "the first is the dock), for maps without a waypoints file")
    p.add_argument("--pedestrians", type=int, default=10, help="simulated people walking about")
    p.add_argument("--clutter", type=int, default=0, help="unmapped boxes the world places")
    p.add_argument("--pairs", default="all", help="'all' ordered pairs of places, or N random legs")
    p.add_argument("--seed", type=int, default=7, help="world and goal seed")
    p.add_argument("--speed", type=float, default=4.0, help="simulated time per wall second")
    p.add_argument("--fast", action="store_true",
                   help="as fast as the machine allows (the result is the same at any speed)")
    p.add_argument("--people-wait", type=float, default=PEOPLE_WAIT_S,
                   help="nav.people_wait_s: how long to wait for people in the way (s)")
    p.add_argument("--people-model", choices=("auto", "jupedsim", "simple"), default="auto",
                   help="sim.people_model: JuPedSim's pedestrians (auto: where installed) or simple walkers")
    p.add_argument("--legs-file", default="",
                   help="JSON lines, one per finished leg; a rerun with the same file skips the legs "
                        "it holds (a long --pairs all run can be done in pieces) and sums them all")
    p.add_argument("--max-legs", type=int, default=0, help="stop after this many new legs (0: all)")
    p.add_argument("--first-leg", type=int, default=1,
                   help="start at this leg (1-based) of the circuit: run a long circuit in shards")
    p.add_argument("--merge", nargs="+", default=[], metavar="LEGS_FILE",
                   help="drive nothing: sum up the legs in these --legs-file files (shards of one run)")


def _circuit(n: int, start: int) -> list[int]:
    """An Eulerian circuit of the complete directed graph on n nodes (Hierholzer)."""
    edges = {i: [j for j in range(n) if j != i] for i in range(n)}
    stack, path = [start], []
    while stack:
        v = stack[-1]
        if edges[v]:
            stack.append(edges[v].pop())
        else:
            path.append(stack.pop())
    return path[::-1]


def _clutter(settings: Any, k: int, rng: np.random.Generator,
             places: list[Any]) -> tuple[tuple[Any, ...], bool]:
    """``k`` unmapped boxes where a path the robot fits through remains between all places, and
    whether it does (see ``nav_places.place_boxes``); fewer boxes when no more fit."""
    from sage_robot.bench.nav_places import BOX_SIZE_M, free_space, place_boxes
    from sage_robot.core.msgs.sim import LowObstacle
    from sage_robot.core.paths import world_map_yaml
    from sage_robot.nav.mapdata import load_map_data

    if k <= 0:
        return (), True
    data = load_map_data(world_map_yaml(settings), None, settings.nav.keepout_mask, settings.nav.speed_mask)
    space = free_space(data.grid, data.keepout)
    boxes, ok = place_boxes(space, k, [(p.pose.x, p.pose.y) for p in places], settings.robot.radius_m, rng)
    return tuple(LowObstacle(f"box{i}", b.x, b.y, *BOX_SIZE_M, b.yaw, CLUTTER_HEIGHT_M, "box")
                 for i, b in enumerate(boxes)), ok


def _auto_places(args: argparse.Namespace, folder: str) -> str:
    """A waypoints file in ``folder`` with ``--places auto N`` places for ``--map``: reachable
    from the dock (the first) by the planner too, not only by the free-space flood fill."""
    from sage_robot.bench.nav_places import auto_places, free_space, write_waypoints
    from sage_robot.core.config import Settings
    from sage_robot.core.errors import ConfigError
    from sage_robot.nav.mapdata import load_for
    from sage_robot.nav.planner import NoPath, plan

    mode, count = args.places
    try:
        n = int(count)
    except ValueError:
        n = -1
    if mode != "auto" or n < 2:
        raise ConfigError(f"--places must be 'auto N' with N >= 2, got {mode!r} {count!r}")
    settings = Settings.model_validate({"nav": {"map": args.map}})
    data = load_for(settings)
    nav, radius = settings.nav, settings.robot.radius_m
    static = data.costmap(radius, nav.inflation_radius_m, nav.cost_scaling_factor)
    dock: list[tuple[float, float]] = []

    def plannable(x: float, y: float) -> bool:
        if not dock:
            dock.append((x, y))
            return True
        try:
            plan(static, dock[0], (x, y))
        except NoPath:
            return False
        return True

    points = auto_places(free_space(data.grid, data.keepout), n, radius,
                         np.random.default_rng((args.seed, PLACES_STREAM)), plannable)
    return str(write_waypoints(Path(folder) / "waypoints.yaml", points, str(data.path)))


def _settings(args: argparse.Namespace, waypoints: str = "") -> Any:
    from sage_robot.core.config import Settings
    from sage_robot.nav.mapdata import load_for

    base = {"map": args.map, "waypoints": waypoints or args.waypoints}
    places = load_for(Settings.model_validate({"nav": base})).places
    if len(places) < 2:
        from sage_robot.core.errors import ConfigError

        raise ConfigError("the nav benchmark needs a waypoints file with two or more places, "
                          "or --places auto N to choose them from the map")
    start = "DOCKING_STATION" if "DOCKING_STATION" in places else places.names()[0]
    return Settings.model_validate({
        "nav": {**base, "initial_place": start, "people_wait_s": args.people_wait},
        "sim": {"world_map": args.map, "speed": None if args.fast else args.speed, "seed": args.seed,
                "pedestrians": args.pedestrians, "clutter": False, "camera_hz": 0,
                "people_model": args.people_model},
    }), list(places)


def run(args: argparse.Namespace) -> dict[str, Any]:
    if args.merge:
        return _merge(args.merge)
    with tempfile.TemporaryDirectory(prefix="sage-bench-nav-") as folder:
        return _run(args, _auto_places(args, folder) if getattr(args, "places", None) else "")


def _run(args: argparse.Namespace, waypoints: str) -> dict[str, Any]:
    from sage_robot.core.errors import ConfigError

    settings, places = _settings(args, waypoints)
    names = [p.name for p in places]
    rng = np.random.default_rng(args.seed)
    start = names.index(settings.nav.initial_place)
    if args.pairs == "all":
        order = _circuit(len(names), start)
    else:
        try:
            n = int(args.pairs)
        except ValueError:
            raise ConfigError(f"--pairs must be 'all' or a number, got {args.pairs!r}") from None
        order = [start]
        for _ in range(n):
            order.append(int(rng.choice([i for i in range(len(names)) if i != order[-1]])))
    legs = [(names[a], names[b]) for a, b in itertools.pairwise(order)]
    if not 1 <= args.first_leg <= len(legs):
        raise ConfigError(f"--first-leg must be between 1 and {len(legs)}, got {args.first_leg}")
    legs = legs[args.first_leg - 1:]
    clutter, paths_remain = _clutter(settings, args.clutter, rng, places)
    head = {"bench": "nav", "map": settings.nav.map or "default building", "pedestrians": args.pedestrians,
            "clutter": args.clutter, "seed": args.seed, "speed": None if args.fast else args.speed,
            "first_leg": args.first_leg, "people_model": _people_model(args.people_model)}
    if waypoints:
        head["places"] = f"auto {len(places)}"
    extra = {"boxes_placed": len(clutter), "paths_remain": paths_remain}
    done: list[dict[str, Any]] = _read_legs(args.legs_file, head, legs) if args.legs_file else []
    todo = legs[len(done):]
    if args.max_legs > 0:
        todo = todo[:args.max_legs]
    t0 = time.perf_counter()
    if todo:
        nav = settings.nav.model_copy(update={"initial_place": todo[0][0]})  # where the last run stopped
        settings = settings.model_copy(update={"nav": nav})

        def keep(rec: dict[str, Any]) -> None:
            if args.legs_file:
                with open(args.legs_file, "a", encoding="utf-8") as f:
                    f.write(json.dumps({**head, **rec}) + "\n")

        scenario = _scenario(clutter)
        floor_m2 = _floor_m2(settings)
        cap = min(args.pedestrians, int(floor_m2 // FLOOR_PER_PERSON_M2))
        sim = settings.sim.model_copy(update={"pedestrians": cap})
        world, placed = _world_that_fits(settings.model_copy(update={"sim": sim}), scenario)
        extra.update(_people_note(args.pedestrians, placed, floor_m2))
        done += asyncio.run(_drive_all(settings, todo, scenario, world, keep))
    wall_s = round(time.perf_counter() - t0, 1)
    return {**head, **extra, "legs_planned": len(legs), **summarize(done), "wall_s": wall_s}


def _people_model(asked: str) -> str:
    """The pedestrian model that runs: ``auto`` is JuPedSim where it is installed."""
    from sage_robot.sim.crowd import jupedsim_available

    return "jupedsim" if asked == "jupedsim" or (asked == "auto" and jupedsim_available()) else "simple"


def _scenario(clutter: tuple[Any, ...]) -> Any:
    from sage_robot.sim.scenario import Scenario

    return Scenario(name="bench_nav", clutter=clutter, default_clutter=False)


def _world_that_fits(settings: Any, scenario: Any) -> tuple[Any, int]:
    """The simulated world with as many of ``settings.sim.pedestrians`` as the simulator finds
    room for, and how many that is. With the floor cap (``FLOOR_PER_PERSON_M2``) a small map
    (the TurtleBot sandbox: 5.6 m across, at most 1.45 m of floor between its pillars and walls)
    gets fewer people than asked: that is the map's size, not a failure of the benchmark; it
    runs with as many as fit and says so (``pedestrians_placed``, ``note``)."""
    from sage_robot.core.errors import ConfigError
    from sage_robot.sim.setup import build_world

    n = settings.sim.pedestrians
    while True:
        sim = settings.sim.model_copy(update={"pedestrians": n})
        try:
            return build_world(settings.model_copy(update={"sim": sim}), scenario), n
        except ConfigError as exc:
            if n <= 0 or "could not find room" not in str(exc):
                raise
            n -= 1


def _floor_m2(settings: Any) -> float:
    """The walkable floor of the world's map (m^2): its largest connected region of free cells."""
    from scipy import ndimage

    from sage_robot.bench.nav_places import free_space
    from sage_robot.core.mapio import read_map
    from sage_robot.core.paths import world_map_yaml

    space = free_space(read_map(world_map_yaml(settings)))
    labels, n = ndimage.label(~space.blocked)
    if n == 0:
        return 0.0
    sizes = np.bincount(labels.ravel())
    sizes[0] = 0
    return float(sizes.max()) * space.res ** 2


def _people_note(asked: int, placed: int, floor_m2: float) -> dict[str, Any]:
    out: dict[str, Any] = {"pedestrians_placed": placed, "floor_m2": round(floor_m2, 1)}
    if placed < asked:
        out["note"] = (f"the map's {floor_m2:.0f} m2 of floor holds {placed} of the {asked} simulated "
                       f"people asked for (at most one per {FLOOR_PER_PERSON_M2:g} m2, Fruin's level of "
                       "service A, and only where the simulator finds room)")
    return out


def _merge(paths: list[str]) -> dict[str, Any]:
    from sage_robot.core.errors import ConfigError

    records: list[dict[str, Any]] = []
    for path in paths:
        try:
            with open(path, encoding="utf-8") as f:
                records += [json.loads(ln) for ln in f if ln.strip()]
        except OSError as exc:
            raise ConfigError(f"cannot read {path}: {exc.strerror}") from None
        except ValueError:
            raise ConfigError(f"{path}: not a --legs-file of JSON lines") from None
    keys = {(r.get("map"), r.get("pedestrians"), r.get("clutter"), r.get("seed")) for r in records}
    if len(keys) > 1:
        raise ConfigError(f"the files hold legs of different runs (map, people, clutter, seed): "
                          f"{sorted(keys, key=str)}")
    head = {k: records[0][k] for k in ("map", "pedestrians", "clutter", "seed")} if records else {}
    return {"bench": "nav", **head, "merged": len(paths), **summarize(records)}


def _read_legs(path: str, head: dict[str, Any], legs: list[tuple[str, str]]) -> list[dict[str, Any]]:
    """The legs a previous run of the same benchmark (same map, people, clutter, seed) finished."""
    from sage_robot.core.errors import ConfigError

    try:
        with open(path, encoding="utf-8") as f:
            lines = [ln for ln in f if ln.strip()]
    except FileNotFoundError:
        return []
    done = []
    for i, line in enumerate(lines):
        try:
            rec = json.loads(line)
        except ValueError:
            raise ConfigError(f"{path}:{i + 1}: not a JSON line") from None
        if any(rec.get(k) != v for k, v in head.items() if k != "speed"):
            raise ConfigError(f"{path}:{i + 1}: written by another run ({rec.get('map')}, "
                              f"{rec.get('pedestrians')} people, seed {rec.get('seed')}); "
                              "use another --legs-file")
        if i >= len(legs) or (rec.get("from"), rec.get("to")) != legs[i]:
            raise ConfigError(f"{path}:{i + 1}: leg {rec.get('from')} -> {rec.get('to')} "
                              f"is not this run's leg {i + 1}")
        done.append(rec)
    return done


async def _drive_all(settings: Any, legs: list[tuple[str, str]], scenario: Any, world: Any,
                     keep: Callable[[dict[str, Any]], None]) -> list[dict[str, Any]]:
    from sage_robot.app.launcher import Launcher, NodeSpec
    from sage_robot.app.runtime import make_context
    from sage_robot.core.clock import SimClock
    from sage_robot.core.node import SIM_STEP_HOOKS
    from sage_robot.nav.localization import LocalizationNode
    from sage_robot.nav.map_server import MapServerNode
    from sage_robot.nav.navigator import NavigatorNode
    from sage_robot.sim.node import SCENARIO_RESOURCE, WORLD_RESOURCE, WorldNode

    ctx = make_context(settings, simulated=True)
    ctx.resources[SCENARIO_RESOURCE] = scenario
    ctx.resources[WORLD_RESOURCE] = world  # built with the people the map holds
    specs = [NodeSpec("sim_world", WorldNode, True), NodeSpec("wheel_odometry", _OdometryNode, True),
             NodeSpec("map_server", MapServerNode, False), NodeSpec("localization", LocalizationNode, False),
             NodeSpec("navigator", NavigatorNode, True)]
    launcher = Launcher(ctx, specs)
    await launcher.start()
    clock = ctx.clock
    assert isinstance(clock, SimClock)
    hooks = ctx.resources[SIM_STEP_HOOKS]

    def physics(dt: float) -> None:
        for hook in hooks:
            hook(dt)

    stop = asyncio.Event()
    from sage_robot.app.runtime import SIM_STEP_S

    stepper = asyncio.get_running_loop().create_task(
        clock.run(SIM_STEP_S, settings.sim.speed, None, stop, physics))
    try:
        deadline = clock.now() + 60.0
        while not all(launcher.health[s.name].state.value == "running" for s in specs):
            if clock.now() > deadline:
                report = launcher.health_report()
                why = "; ".join(f"{name}: {h['last_error']}" for name, h in report.items()
                                if h.get("state") != "running" and h.get("last_error"))
                raise SageError(f"nodes did not start: {why or report}")
            await clock.sleep(0.1)
        return await _legs(ctx, launcher, legs, keep)
    finally:
        stop.set()
        await asyncio.wait({stepper}, timeout=10)
        await launcher.stop()


async def _legs(ctx: Any, launcher: Any, legs: list[tuple[str, str]],
                keep: Callable[[dict[str, Any]], None]) -> list[dict[str, Any]]:
    from sage_robot.core import topics
    from sage_robot.core.geometry import wrap_angle
    from sage_robot.core.msgs.nav import NavigateGoal
    from sage_robot.nav.planner import NoPath, plan
    from sage_robot.sim.node import WORLD_RESOURCE

    clock, bus = ctx.clock, ctx.bus
    world = ctx.resources[WORLD_RESOURCE]
    nav = launcher.nodes["navigator"]
    static = nav.data.costmap(ctx.settings.robot.radius_m, ctx.settings.nav.inflation_radius_m,
                              ctx.settings.nav.cost_scaling_factor)
    errs_m: list[float] = []
    errs_deg: list[float] = []

    async def sample() -> None:
        while True:
            await clock.sleep(SAMPLE_PERIOD_S)
            est = nav.pose()
            if est is not None:
                errs_m.append(math.hypot(est[0] - world.x, est[1] - world.y))
                errs_deg.append(math.degrees(abs(wrap_angle(est[2] - world.theta))))

    sampler = asyncio.get_running_loop().create_task(sample())
    waiting = _WaitWatch(clock)
    untap = bus.add_tap(waiting.see)
    hits: list[Any] = []  # the simulator's Collision records (what, where, how fast)
    world.on_collision.append(hits.append)
    await clock.sleep(1.0)
    records = []
    for a, b in legs:
        goal = nav.data.places.get(b).pose
        c0, d0, t0 = world.collisions, world.distance_m, clock.now()
        waiting.reset()
        errs_m.clear()
        errs_deg.clear()
        hits.clear()
        try:
            shortest = plan(static, (world.x, world.y), (goal.x, goal.y)).length_m
        except NoPath:
            shortest = math.nan
        handle = await bus.actions.send_goal(topics.NAVIGATE_TO, NavigateGoal(place=b))
        try:
            res = await clock.wait_for(handle.result(), LEG_TIMEOUT_S)
            ok, why = res.ok, res.message or str(getattr(res.value, "reason", "") or "")
        except asyncio.TimeoutError:
            await handle.cancel()
            ok, why = False, f"timed out after {LEG_TIMEOUT_S:g} s"
        short_m = math.hypot(goal.x - world.x, goal.y - world.y)
        if ok and short_m > ARRIVED_M:  # the simulator's truth, not the navigator's word
            ok, why = False, (f"{SAID_ARRIVED} {short_m:.1f} m from the goal "
                              f"({why or 'no note'})")
        rec = {"from": a, "to": b, "ok": ok, "reason": "" if ok else why,
               "collisions": world.collisions - c0, "time_s": round(clock.now() - t0, 1),
               "length_m": round(world.distance_m - d0, 2), "shortest_m": round(shortest, 2),
               "short_m": round(short_m, 2), "waited_s": round(waiting.waited(), 1),
               "excuse_me": waiting.excuse_me,
               "loc_samples": len(errs_m), "loc_sq_m": round(float(np.sum(np.square(errs_m))), 6),
               "loc_sq_deg": round(float(np.sum(np.square(errs_deg))), 4),
               "hits": [{"kind": h.kind, "name": h.name, "x": round(h.x, 2), "y": round(h.y, 2),
                         "speed_mps": round(h.speed_mps, 2)} for h in hits]}
        if not ok:  # who was around when it gave up, to tell a crowd from a planner fault
            rec["robot"] = [round(world.x, 2), round(world.y, 2), round(world.theta, 2)]
            rec["people_near"] = [
                {"behaviour": p.behaviour, "x": round(p.x, 2), "y": round(p.y, 2),
                 "moving": round(p.moving, 2), "d": round(math.hypot(p.x - world.x, p.y - world.y), 2)}
                for p in world.crowd.people if math.hypot(p.x - world.x, p.y - world.y) < NEAR_PERSON_M]
        records.append(rec)
        keep(rec)
    sampler.cancel()
    untap()
    return records


class _WaitWatch:
    """Sees every publication (a bus tap): the time the navigator spends in
    ``waiting_for_people`` (its NAV_STATE) and the events that ask people to step aside."""

    def __init__(self, clock: Any) -> None:
        self.clock = clock
        self.since: float | None = None  # simulated time the current wait began
        self.total = 0.0
        self.excuse_me = 0

    def reset(self) -> None:
        self.total, self.excuse_me = 0.0, 0
        if self.since is not None:
            self.since = self.clock.now()

    def waited(self) -> float:
        return self.total + (self.clock.now() - self.since if self.since is not None else 0.0)

    def see(self, name: str, msg: Any) -> None:
        from sage_robot.core import topics
        from sage_robot.core.msgs.nav import NavState

        if name == topics.NAV_STATE:
            if msg.state is NavState.WAITING_FOR_PEOPLE:
                if self.since is None:
                    self.since = self.clock.now()
            elif self.since is not None:
                self.total += self.clock.now() - self.since
                self.since = None
        elif name == topics.EVENTS and (msg.kind in EXCUSE_ME_KINDS or "excuse me" in msg.message.lower()):
            self.excuse_me += 1


def summarize(records: list[dict[str, Any]]) -> dict[str, Any]:
    """Success, collisions, failures, path and time figures and localization RMSE over legs."""
    good = [r for r in records if r["ok"] and r["shortest_m"] > 0]
    n_loc = sum(r["loc_samples"] for r in records)
    return {
        "legs": len(records),
        "success_rate": round(sum(r["ok"] for r in records) / max(1, len(records)), 3),
        "collisions": int(sum(r["collisions"] for r in records)),
        "failures": [{k: r[k] for k in ("from", "to", "reason")} for r in records if not r["ok"]],
        "collision_details": [{"from": r["from"], "to": r["to"], **h}
                              for r in records for h in r.get("hits", [])],
        "path_length_vs_shortest": round(float(np.median([r["length_m"] / r["shortest_m"] for r in good])), 3)
        if good else None,
        "median_leg_time_s": round(float(np.median([r["time_s"] for r in good])), 1) if good else None,
        "mean_speed_mps": round(sum(r["length_m"] for r in good)
                                / max(1e-9, sum(r["time_s"] for r in good)), 3),
        "localization_rmse_m": round(math.sqrt(sum(r["loc_sq_m"] for r in records) / n_loc), 3)
        if n_loc else None,
        "localization_rmse_deg": round(math.sqrt(sum(r["loc_sq_deg"] for r in records) / n_loc), 2)
        if n_loc else None,
        "sim_time_s": round(sum(r["time_s"] for r in records), 1),
        "time_waiting_s": round(sum(r.get("waited_s", 0.0) for r in records), 1),
        "excuse_me": int(sum(r.get("excuse_me", 0) for r in records)),
        "arrived_short": sum(not r["ok"] and r["reason"].startswith(SAID_ARRIVED) for r in records),
    }


def _odometry_node() -> Any:
    from sage_robot.core import topics
    from sage_robot.core.geometry import compose, relative
    from sage_robot.core.msgs import Odometry, Pose2D, Twist
    from sage_robot.core.node import Node

    class OdometryNode(Node):
        """Wheel odometry from the simulated body's true motion, reading ODOM_SCALE_ERROR long."""

        name = "wheel_odometry"

        async def setup(self) -> None:
            self._last: tuple[float, float, float] | None = None
            self._odom = (0.0, 0.0, 0.0)
            self.subscribe(topics.SIM_TRUTH, Odometry, self._on_truth, maxsize=100)

        def _on_truth(self, msg: Odometry) -> None:
            pose = msg.pose.as_tuple()
            if self._last is not None:
                dx, dy, dth = relative(self._last, pose)
                k = 1.0 + ODOM_SCALE_ERROR
                self._odom = compose(self._odom, (dx * k, dy * k, dth))
            self._last = pose
            twist = Twist(msg.twist.linear_x * (1.0 + ODOM_SCALE_ERROR), msg.twist.angular_z)
            self.bus.publish(topics.ODOM, Odometry(msg.stamp, Pose2D(*self._odom), twist))

    return OdometryNode


class _Lazy:
    """Builds the odometry node class on first use, so importing this module stays light."""

    def __call__(self, ctx: Any) -> Any:
        return _odometry_node()(ctx)


_OdometryNode = _Lazy()
