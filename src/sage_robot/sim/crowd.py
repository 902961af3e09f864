"""The crowd behind the world: which pedestrian model moves the simulated people.

``CrowdModel`` is what :class:`~sage_robot.sim.world.World` asks of a crowd. Two backends:

- ``simple``: the hand-written walkers of ``sim/people.py`` (numpy + stdlib, always there);
- ``jupedsim``: the same people moved by JuPedSim's collision-free speed model
  (``sim/people_jps.py``; LGPL-3.0, the optional extra ``people``): they avoid each other,
  the walls of the map's free space and the robot.

``sim.people_model: auto`` picks JuPedSim when it imports (and the simple walkers on a map
it cannot take: a rotated origin). When the robot says "excuse me"
(the navigator's ``blocked_by_people`` event) the world picks, among the people in front of
it, where each one steps aside (:func:`aside_path`); a seeded share
(``sim.people_ignore_share``) stays put.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, Protocol

import numpy as np

from sage_robot.core.msgs import OccupancyGrid
from sage_robot.sim.people import PERSON_RADIUS_M, WALL_MARGIN_M, Crowd, Lanes, PersonState

PEOPLE_MODELS = ("auto", "jupedsim", "simple")
ASK_RANGE_M = 5.0  # people this close to the robot, in front of it, hear "excuse me"
ASIDE_CLEAR_M = 0.3  # a person steps this far clear of the robot's way (beyond both radii)
ASIDE_STEPS_M = (0.5, 0.8, 1.1, 1.5, 2.0, 2.5, 3.0)  # how far people look for a spot
ASIDE_DIRECTIONS = 24  # directions tried at each distance
LOS_STEP_M = 0.05  # sampling of the straight walk to the spot


class CrowdModel(Protocol):
    """What the world needs of a crowd (both backends provide it)."""

    people: list[PersonState]
    lanes: Lanes | None
    robot_speed: float
    is_free: Any

    def bodies(self) -> np.ndarray: ...

    def legs(self) -> np.ndarray: ...

    def step(self, dt: float, t: float, robot: tuple[float, float, float], robot_radius: float) -> None: ...

    def send_aside(self, person: PersonState, path: list[tuple[float, float]]) -> None: ...


def jupedsim_available() -> bool:
    try:
        import jupedsim  # noqa: F401
    except ImportError:
        return False
    return True


def make_crowd(
    model: str,
    people: list[PersonState],
    lanes: Lanes | None,
    clearance: Callable[[float, float], float],
    rng: np.random.Generator,
    line_of_sight: Any,
    *,
    grid: OccupancyGrid,
    start: tuple[float, float, float],
    robot_radius: float,
) -> CrowdModel:
    """The crowd ``model`` names (auto | jupedsim | simple)."""
    if model not in PEOPLE_MODELS:
        raise ValueError(f"sim.people_model must be one of {', '.join(PEOPLE_MODELS)}, got {model!r}")
    if model == "jupedsim" and not jupedsim_available():
        raise ValueError("sim.people_model is 'jupedsim' but jupedsim is not installed "
                         "(pip install 'sage-robot[people]', or use 'auto' or 'simple')")
    if model == "simple" or (model == "auto" and not jupedsim_available()):
        return Crowd(people, lanes, clearance, rng, line_of_sight)
    from sage_robot.sim.people_jps import JpsCrowd

    try:
        return JpsCrowd(people, lanes, clearance, rng, line_of_sight, grid=grid, start=start,
                        robot_radius=robot_radius)
    except ValueError:
        if model == "jupedsim":
            raise
        return Crowd(people, lanes, clearance, rng, line_of_sight)  # auto: a map JuPedSim cannot take


def asked_people(people: list[PersonState], robot: tuple[float, float, float]) -> list[PersonState]:
    """Who hears "excuse me": people within ASK_RANGE_M in front of the robot, nearest first."""
    c, s = math.cos(robot[2]), math.sin(robot[2])
    near = [
        p for p in people
        if math.hypot(p.x - robot[0], p.y - robot[1]) <= ASK_RANGE_M
        and (p.x - robot[0]) * c + (p.y - robot[1]) * s > 0.0
    ]
    return sorted(near, key=lambda p: (math.hypot(p.x - robot[0], p.y - robot[1]), p.id))


def aside_path(
    p: PersonState,
    robot: tuple[float, float, float],
    robot_radius: float,
    free: Callable[[float, float], bool],
) -> list[tuple[float, float]]:
    """Where ``p`` goes to make way, as 1-2 straight legs: the nearest free spot out of the
    robot's way (ASIDE_CLEAR_M beyond both radii beside the line ahead of it, or behind it),
    reached straight, or by walking on ahead (away from the robot: out of a corridor or a
    doorway) and then sideways. [] when there is none (a dead end): they stay."""
    c, s = math.cos(robot[2]), math.sin(robot[2])
    clear = robot_radius + PERSON_RADIUS_M + ASIDE_CLEAR_M

    def out_of_way(x: float, y: float) -> bool:
        dx, dy = x - robot[0], y - robot[1]
        return abs(-dx * s + dy * c) >= clear or dx * c + dy * s <= -clear

    for dist in ASIDE_STEPS_M:
        for k in range(ASIDE_DIRECTIONS):  # straight to the side (or back)
            a = 2.0 * math.pi * k / ASIDE_DIRECTIONS
            x, y = p.x + dist * math.cos(a), p.y + dist * math.sin(a)
            if out_of_way(x, y) and free(x, y) and _walkable(p.x, p.y, x, y, free):
                return [(x, y)]
    for on in ASIDE_STEPS_M:  # on ahead, then to the side
        vx, vy = p.x + on * c, p.y + on * s
        if not (free(vx, vy) and _walkable(p.x, p.y, vx, vy, free)):
            break
        for side in ASIDE_STEPS_M:
            for sign in (1.0, -1.0):
                x, y = vx - sign * side * s, vy + sign * side * c
                if out_of_way(x, y) and free(x, y) and _walkable(vx, vy, x, y, free):
                    return [(vx, vy), (x, y)]
    return []


def _walkable(x0: float, y0: float, x1: float, y1: float, free: Callable[[float, float], bool]) -> bool:
    n = max(int(math.hypot(x1 - x0, y1 - y0) / LOS_STEP_M), 1)
    return all(free(x0 + (x1 - x0) * i / n, y0 + (y1 - y0) * i / n) for i in range(1, n))


def person_fits(clearance: Callable[[float, float], float], is_free: Any) -> Callable[[float, float], bool]:
    """(x, y) -> True where a person's body fits on known-free floor."""

    def fits(x: float, y: float) -> bool:
        return clearance(x, y) >= PERSON_RADIUS_M + WALL_MARGIN_M and (is_free is None or bool(is_free(x, y)))

    return fits
