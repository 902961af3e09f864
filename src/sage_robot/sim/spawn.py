"""Where simulated people start: a seeded default crowd, or the people a scenario lists."""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from typing import Any

import numpy as np

from sage_robot.core.errors import ConfigError
from sage_robot.sim.people import (
    APPROACH_DELAY_S,
    APPROACH_STAY_S,
    APPROACH_STOP_M,
    PERSON_RADIUS_M,
    SPAWN_MIN_DIST_M,
    WALK_SPEED_MPS,
    Lanes,
    PersonState,
)
from sage_robot.sim.walking_group import GROUP_WALK_MPS, slot_point, slots

MIX = ("walker", "stander", "approacher", "group", "walking_group")  # then walkers
GROUP_SIZE = 3
WALKING_GROUP_SIZE = 2  # most groups on foot are pairs (Moussaïd et al. 2010)
MAX_COMPANIONS = 3  # a scenario walker walks with at most this many companions
GROUP_RING_M = 0.55  # members stand on a circle this wide around the group's centre
GROUP_FROM_PLACE_M = (1.5, 2.5)  # a group stands this far beyond a place...
GROUP_SPREAD_RAD = math.pi / 3  # ...within this angle of the direction the place faces
APPROACHER_FROM_ROBOT_M = (3.0, 10.0)
SPAWN_TRIES = 200
SMALL_FLOOR_MIN_DIST_M = 2.0  # where no spot is SPAWN_MIN_DIST_M from the robot, people start this far
# People who stand for good (the stander, a standing group) stand at least this far from every
# named place, where the floor allows: a tour stop is where visitors come and go, not where
# someone stays for hours (issue #20: in the TurtleBot sandbox a stander drawn 0.3 m from a place
# made every leg to it end short, "someone is standing at the spot"). The visitor who walks up
# to the robot and stays a while still comes anywhere.
STAND_OFF_PLACE_M = 1.2  # (m): a robot at the place keeps 0.7 m from them
BEHAVIOURS = ("walker", "stander", "group", "approacher")
PERSON_KEYS = {"kind", "at", "to", "heading", "speed", "start_s", "stay_s", "companions"}

Clearance = Callable[[float, float], np.ndarray]
SampleFree = Callable[[np.random.Generator], tuple[float, float]]
LineOfSight = Callable[[float, float, float, float], bool]


def spawn_crowd(
    n: int,
    rng: np.random.Generator,
    robot_xy: tuple[float, float],
    lanes: Lanes | None,
    places: list[tuple[float, float, float]],
    clearance: Clearance,
    sample_free: SampleFree,
    line_of_sight: LineOfSight,
    robot_yaw: float = 0.0,
    keep_off: list[tuple[float, float]] | None = None,
) -> list[PersonState]:
    """``n`` people, in the mix walker, stander, approacher, a group of three standing, a
    pair walking together, then walkers.

    ``places`` are (x, y, facing) of the named places (groups gather beyond one of them);
    people who stand for good keep ``STAND_OFF_PLACE_M`` from the spots in ``keep_off`` (every
    place, the dock too; default: ``places``) where the floor allows."""
    off = [(x, y) for x, y, _ in places] if keep_off is None else keep_off
    off_places = functools.partial(_off_places, off)
    people: list[PersonState] = []

    def clear(x: float, y: float, need: float) -> bool:
        return float(clearance(x, y)[0]) >= need

    near_m = [SPAWN_MIN_DIST_M]  # how far from the robot people start (less on a small floor)

    def far(x: float, y: float, lo: float | None = None, hi: float = math.inf) -> bool:
        d = math.hypot(x - robot_xy[0], y - robot_xy[1])
        return (near_m[0] if lo is None else lo) <= d <= hi

    def spot(ok: Callable[[float, float], bool], edge: bool = False, relax: bool = True,
             prefer: Callable[[float, float], bool] | None = None) -> tuple[float, float]:
        found = _draw(rng, lanes, sample_free, clear, ok, edge, prefer)
        if found is None and relax and near_m[0] > SMALL_FLOOR_MIN_DIST_M:
            # a floor with no room SPAWN_MIN_DIST_M from the robot (the TurtleBot sandbox is 5.6 m
            # across): people start nearer, from here on (a large map never gets here: same crowd)
            near_m[0] = SMALL_FLOOR_MIN_DIST_M
            found = _draw(rng, lanes, sample_free, clear, ok, edge)
        if found is None:
            raise ConfigError("could not find room for the simulated people; lower sim.pedestrians")
        return found

    fx = robot_xy[0] + APPROACH_STOP_M * math.cos(robot_yaw)
    fy = robot_xy[1] + APPROACH_STOP_M * math.sin(robot_yaw)
    k = 0
    while len(people) < n:
        kind = MIX[k] if k < len(MIX) else "walker"
        k += 1
        pid = len(people)
        heading = float(rng.uniform(-math.pi, math.pi))
        if kind == "group" and places:  # where no group fits, the mix goes on without one
            size = min(GROUP_SIZE, n - len(people))
            people += _group(pid, size, rng, places, clear, far, off_places)
            continue
        if kind == "walking_group" and n - len(people) >= WALKING_GROUP_SIZE:
            room = slots(WALKING_GROUP_SIZE)

            def fits(x: float, y: float, h: float = heading, room: Any = room) -> bool:
                return far(x, y) and all(clear(*slot_point((x, y, h), s[1]), PERSON_RADIUS_M + 0.1)
                                         for s in room)

            x, y = spot(fits)
            people += walking_party(pid, (x, y, heading), WALKING_GROUP_SIZE - 1,
                                    float(rng.uniform(*GROUP_WALK_MPS)))
            continue
        if kind == "approacher":
            # Somewhere in sight of the spot in front of the robot where they will stand.
            try:
                x, y = spot(lambda x, y: far(x, y, *APPROACHER_FROM_ROBOT_M) and line_of_sight(x, y, fx, fy),
                            relax=False)
            except ConfigError:
                x, y = spot(far)
            people.append(
                PersonState(
                    pid,
                    x,
                    y,
                    heading,
                    "approacher",
                    speed_mps=1.0,
                    start_s=float(rng.uniform(*APPROACH_DELAY_S)),
                    stay_s=float(rng.uniform(*APPROACH_STAY_S)),
                )
            )
            continue
        # standers by a wall, out of the way (and off the places where the floor allows)
        x, y = spot(far, edge=True, prefer=off_places) if kind == "stander" else spot(far)
        behaviour = "stander" if kind == "stander" else "walker"
        people.append(
            PersonState(pid, x, y, heading, behaviour, speed_mps=float(rng.uniform(*WALK_SPEED_MPS)))
        )
    return people


def _off_places(spots: list[tuple[float, float]], x: float, y: float) -> bool:
    return all(math.hypot(x - px, y - py) >= STAND_OFF_PLACE_M for px, py in spots)


def _draw(rng: np.random.Generator, lanes: Lanes | None, sample_free: SampleFree,
          clear: Callable[[float, float, float], bool], ok: Callable[[float, float], bool],
          edge: bool, prefer: Callable[[float, float], bool] | None = None) -> tuple[float, float] | None:
    """A free spot a person fits on that ``ok`` accepts, in SPAWN_TRIES draws; None if none.
    With ``prefer``: one it also accepts, if the draws find one, else as without."""
    if prefer is not None:
        found = _draw(rng, lanes, sample_free, clear, lambda x, y: ok(x, y) and prefer(x, y), edge)
        if found is not None:
            return found
    for _ in range(SPAWN_TRIES):
        if lanes is not None:
            x, y, _ = lanes.random_point(rng, PERSON_RADIUS_M + 0.1, edge)
        else:
            x, y = sample_free(rng)
        if clear(x, y, PERSON_RADIUS_M + 0.1) and ok(x, y):
            return (x, y)
    return None


def _group(
    pid: int,
    size: int,
    rng: np.random.Generator,
    places: list[tuple[float, float, float]],
    clear: Callable[[float, float, float], bool],
    far: Callable[[float, float], bool],
    off_places: Callable[[float, float], bool],
) -> list[PersonState]:
    """A group of ``size`` standing in a ring beyond one of ``places``, every member off every
    place where the floor allows; [] when there is no room for one."""
    fallback = None
    for _ in range(SPAWN_TRIES):
        px, py, facing = places[int(rng.integers(len(places)))]
        # Beyond the place as one arrives (places face into their rooms): not in the doorway.
        a = facing + float(rng.uniform(-GROUP_SPREAD_RAD, GROUP_SPREAD_RAD))
        r = float(rng.uniform(*GROUP_FROM_PLACE_M))
        cx, cy = px + r * math.cos(a), py + r * math.sin(a)
        if clear(cx, cy, GROUP_RING_M + PERSON_RADIUS_M + 0.1) and far(cx, cy):
            if all(off_places(cx + GROUP_RING_M * math.cos(a + 2 * math.pi * j / size),
                              cy + GROUP_RING_M * math.sin(a + 2 * math.pi * j / size)) for j in range(size)):
                break
            fallback = fallback or (a, cx, cy)  # on a small floor: by a place, if nowhere else
    else:
        if fallback is None:  # no room for a standing group (a floor 1.45 m between pillars)
            return []
        a, cx, cy = fallback
    out = []
    for j in range(size):
        b = a + 2 * math.pi * j / size
        x, y = cx + GROUP_RING_M * math.cos(b), cy + GROUP_RING_M * math.sin(b)
        out.append(PersonState(pid + j, x, y, math.atan2(cy - y, cx - x), "group", speed_mps=0.0))
    return out


def walking_party(pid: int, leader: tuple[float, float, float], companions: int,
                  speed_mps: float) -> list[PersonState]:
    """A walker (id ``pid``, at ``leader``) and ``companions`` people in single file behind it,
    who walk with it (``sim/walking_group.py``)."""
    x, y, heading = leader
    out = [PersonState(pid, x, y, heading, "walker", speed_mps=speed_mps)]
    for k, (_, in_file) in enumerate(slots(companions + 1)):
        cx, cy = slot_point(leader, in_file)
        out.append(PersonState(pid + 1 + k, cx, cy, heading, "companion", speed_mps=speed_mps,
                               leader=pid, slot=k))
    return out


def people_from_specs(
    specs: list[dict[str, Any]], first_id: int, resolve: Callable[[Any, str], tuple[float, float, float]]
) -> list[PersonState]:
    """Scenario people: ``{kind, at, to, heading, speed, start_s, stay_s, companions}``;
    ``at``/``to`` are [x, y] or a place name (``resolve`` turns them into poses); a walker with
    ``companions: N`` (1-3) walks with N more people, who start in single file behind it."""
    out: list[PersonState] = []
    for i, spec in enumerate(specs):
        where = f"people[{i}]"
        if not isinstance(spec, dict):
            raise ConfigError(f"{where}: expected a mapping, got {spec!r}")
        unknown = set(spec) - PERSON_KEYS
        if unknown:
            raise ConfigError(
                f"{where}: unknown key(s) {', '.join(sorted(unknown))}; allowed: "
                f"{', '.join(sorted(PERSON_KEYS))}"
            )
        kind = spec.get("kind", "stander")
        if kind not in BEHAVIOURS:
            raise ConfigError(f"{where}: kind must be one of {', '.join(BEHAVIOURS)}, got {kind!r}")
        if "at" not in spec:
            raise ConfigError(f"{where}: needs 'at' ([x, y] or a place name)")
        x, y, yaw = resolve(spec["at"], f"{where}.at")
        heading = float(spec.get("heading", yaw))
        companions = _companions(spec, kind, where)
        party = walking_party(first_id + len(out), (x, y, heading), companions,
                              float(spec.get("speed", 1.0)))
        p = party[0]
        p.behaviour = kind
        if "to" in spec:
            tx, ty, _ = resolve(spec["to"], f"{where}.to")
            p.patrol = [(tx, ty), (x, y)]
            p.fixed = True
        p.start_s = float(spec.get("start_s", 0.0))
        p.stay_s = float(spec.get("stay_s", 60.0))
        out += party
    return out


def _companions(spec: dict[str, Any], kind: str, where: str) -> int:
    value = spec.get("companions", 0)
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= MAX_COMPANIONS:
        raise ConfigError(f"{where}.companions must be a whole number from 0 to {MAX_COMPANIONS}, "
                          f"got {value!r}")
    if value and kind != "walker":
        raise ConfigError(f"{where}: only a walker walks with companions (kind is {kind!r})")
    return value
