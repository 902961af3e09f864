"""People who behave like people: the JuPedSim crowd backend, and stepping aside when asked.

The world is stepped directly (simulated time, 10 ms steps). Tests of the ``jupedsim``
backend skip with a clear message when the optional extra is not installed; the doorway
tests run on both backends.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from sage_robot.sim.crowd import make_crowd
from sage_robot.sim.lidar import LidarSpec
from sage_robot.sim.people import PERSON_RADIUS_M, PersonState
from sage_robot.sim.world import World

from ..support.grids import fill, room

DT_S = 0.01
ROBOT_RADIUS_M = 0.25
BODY_CONTACT_M = PERSON_RADIUS_M + ROBOT_RADIUS_M
WALL_TOLERANCE_M = 0.05  # one map cell
PASSED_M = 1.0  # a walker of the counter-flow is through when this close to its end (along x)

try:
    import jupedsim  # noqa: F401

    HAVE_JPS = True
except ImportError:
    HAVE_JPS = False
needs_jps = pytest.mark.skipif(
    not HAVE_JPS, reason="jupedsim is not installed (optional extra: pip install 'sage-robot[people]')"
)
BACKENDS = [pytest.param("simple"), pytest.param("jupedsim", marks=needs_jps)]


def _world(grid, start, people, model: str, **kw) -> World:
    quiet = LidarSpec(noise_fraction=0.0, noise_floor_m=0.0, dropout_probability=0.0)
    return World(grid, start, robot_radius=ROBOT_RADIUS_M, lidar=quiet, people=people,
                 people_model=model, **kw)


def _run(world: World, seconds: float, each=None) -> None:
    for _ in range(round(seconds / DT_S)):
        world.step(DT_S)
        if each is not None:
            each(world)


def _corridor(length_m: float = 16.0, width_m: float = 2.0):
    """A corridor ``width_m`` wide inside one-cell walls (y from 0.05 to 0.05 + width)."""
    return room(length_m + 0.1, width_m + 0.1)


def _walker(pid: int, x: float, y: float, to: tuple[float, float], speed: float = 1.2) -> PersonState:
    return PersonState(pid, x, y, behaviour="walker", speed_mps=speed, fixed=True, patrol=[to])


# ---------------------------------------------------------------- counter-flow, safety
def _counter_flow(seed: int = 3) -> tuple[World, list[tuple[float, float]]]:
    rng = np.random.default_rng(seed)
    people, ends = [], []
    for i in range(4):  # four walk east, four walk west, in a 2 m corridor
        east = _walker(2 * i, 1.0 + 0.9 * i, float(rng.uniform(0.5, 1.6)), (13.0, 1.05))
        west = _walker(2 * i + 1, 13.0 - 0.9 * i, float(rng.uniform(0.5, 1.6)), (1.0, 1.05))
        people += [east, west]
        ends += [(13.0, 1.05), (1.0, 1.05)]
    return _world(_corridor(), (15.3, 1.05, math.pi), people, "jupedsim", seed=seed), ends


@needs_jps
def test_counter_flow_in_a_2m_corridor_passes_through() -> None:
    world, ends = _counter_flow()
    reached = [False] * len(ends)

    closest = math.inf

    def see(w: World) -> None:
        nonlocal closest
        xy = np.array([(p.x, p.y) for p in w.crowd.people])
        gaps = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1))
        closest = min(closest, float(gaps[np.triu_indices(len(xy), 1)].min()))
        for i, p in enumerate(w.crowd.people):
            reached[i] = reached[i] or abs(p.x - ends[i][0]) < PASSED_M  # through the stream

    _run(world, 40.0, see)
    assert all(reached), [(p.id, round(p.x, 2), round(p.y, 2)) for p in world.crowd.people]
    assert closest >= 2 * PERSON_RADIUS_M - 1e-6, closest  # nobody walks through anybody


@needs_jps
def test_same_seed_same_walk() -> None:
    runs = []
    for _ in range(2):
        world, _ = _counter_flow(seed=11)
        _run(world, 8.0)
        runs.append([(p.x, p.y, p.theta) for p in world.crowd.people])
    assert runs[0] == runs[1]


@needs_jps
def test_people_stay_on_the_floor_and_out_of_the_robot() -> None:
    """Walkers stream both ways past a robot that drives back and forth in the corridor:
    no body ever overlaps the robot's or a wall."""
    people = [_walker(i, 1.0 + 0.7 * i, 0.6 + 0.25 * (i % 4), (14.0, 1.05)) for i in range(4)]
    people += [_walker(4 + i, 14.5 - 0.7 * i, 0.6 + 0.25 * (i % 4), (1.0, 1.05)) for i in range(4)]
    world = _world(_corridor(), (7.5, 1.05, 0.0), people, "jupedsim")
    closest_robot, closest_wall, steps = math.inf, math.inf, 0

    def see(w: World) -> None:
        nonlocal closest_robot, closest_wall, steps
        steps += 1
        w.move(DT_S, 0.3 if (steps // 500) % 2 == 0 else -0.3, 0.0)
        for p in w.crowd.people:
            closest_robot = min(closest_robot, math.hypot(p.x - w.x, p.y - w.y))
            closest_wall = min(closest_wall, w.raycaster.clearance_at(p.x, p.y))

    _run(world, 30.0, see)
    assert closest_robot >= BODY_CONTACT_M, closest_robot
    assert closest_wall >= PERSON_RADIUS_M - WALL_TOLERANCE_M, closest_wall
    assert world.distance_m > 1.0  # the robot did drive among them


@needs_jps
def test_a_robot_off_the_peoples_floor_does_not_stop_the_world() -> None:
    """The robot on floor the walkable polygon does not hold (near a wall its simplification
    cut off, or across a wall from the people: JuPedSim refuses such a target, and on
    willow the world crashed over it): its agent waits at the nearest point inside; people
    walk on."""
    grid = room(12.0, 6.0)
    fill(grid, 6.0, 0.0, 6.2, 6.0)  # two rooms, no door
    walker = _walker(0, 1.0, 3.0, (5.0, 3.0))
    world = _world(grid, (3.0, 1.0, 0.0), [walker], "jupedsim")
    world.x, world.y = 9.0, 3.0  # the robot is now in the other room
    _run(world, 3.0)
    assert walker.x > 3.0, "the walker did not walk on"


@pytest.mark.parametrize("model", BACKENDS)
def test_a_walker_held_up_by_the_robot_turns_away_on_a_map_without_lanes(model: str) -> None:
    """A robot stands in a 1 m corridor no one can pass it in: a walker coming its way waits a
    while, then goes elsewhere (it used to wait for good, and the robot waited for it)."""
    walker = PersonState(0, 2.0, 0.55, behaviour="walker", speed_mps=1.0, route=[(14.0, 0.55)])
    world = _world(_corridor(width_m=1.0), (7.0, 0.55, math.pi), [walker], model, seed=2)
    _run(world, 5.0)
    assert math.hypot(walker.x - 7.0, walker.y - 0.55) < 1.5, "the walker never reached the robot"
    away = []
    _run(world, 20.0, lambda w: away.append(math.hypot(walker.x - 7.0, walker.y - 0.55)))
    assert max(away) > 1.5, f"the walker stayed at the robot: at most {max(away):.2f} m from it"
    assert walker.x < 7.0


@needs_jps
def test_people_wedged_in_a_narrow_gap_give_up_and_go_elsewhere() -> None:
    """Three walkers meet in a 0.7 m gap in a wall and wedge. JuPedSim's agents then jitter in
    place, millimetres to and fro every tick, so the speed of one tick never said "stuck", and
    they stood there for good (on the TurtleBot sandbox four people stood 200 s between the
    pillars, and the robot waited for them). Now each gives its goal up and walks on."""
    grid = room(8.0, 4.0)
    fill(grid, 4.0, 0.0, 4.2, 1.65)
    fill(grid, 4.0, 2.35, 4.2, 4.0)
    people = [PersonState(0, 2.0, 2.0, behaviour="walker", speed_mps=1.0, route=[(7.0, 2.0)]),
              PersonState(1, 6.0, 2.05, behaviour="walker", speed_mps=1.0, route=[(1.0, 2.0)]),
              PersonState(2, 6.5, 1.8, behaviour="walker", speed_mps=1.0, route=[(1.0, 2.0)])]
    world = _world(grid, (0.8, 3.5, 0.0), people, "jupedsim", seed=1)
    _run(world, 5.0)
    jammed = [(p.x, p.y) for p in people]
    assert all(math.hypot(x - 4.1, y - 2.0) < 0.8 for x, y in jammed), f"no jam at the gap: {jammed}"
    farthest = [0.0] * len(people)

    def note(w: World) -> None:
        for i, p in enumerate(w.crowd.people):
            farthest[i] = max(farthest[i], math.hypot(p.x - jammed[i][0], p.y - jammed[i][1]))

    _run(world, 25.0, note)
    assert min(farthest) > 0.5, f"someone stayed wedged: farthest from the jam {farthest} m"


@pytest.mark.parametrize("model", BACKENDS)
def test_a_walker_whose_way_aside_leads_past_the_robot_does_not_stand_there_for_good(model: str) -> None:
    """Asked aside, a walker right in front of the robot was given a spot behind it: the way
    there passes the robot, which nobody walks into, so the walker stood at the robot's front
    for good (its turn-back route came after the way aside). Now it gives that way up."""
    walker = PersonState(0, 3.65, 2.0, behaviour="walker", speed_mps=1.0, route=[(3.65, 2.0)])
    world = _world(room(6.0, 4.0), (3.0, 2.0, 0.0), [walker], model, seed=2)
    world.crowd.send_aside(walker, [(1.5, 2.0)])
    moved, near = [], []

    def note(_w: World) -> None:
        moved.append(math.hypot(walker.x - 3.65, walker.y - 2.0))
        near.append(math.hypot(walker.x - 3.0, walker.y - 2.0))

    _run(world, 30.0, note)
    assert not walker.aside
    assert max(moved) > 1.0, f"the walker stood at the robot's front: at most {max(moved):.2f} m from there"
    assert min(near) >= BODY_CONTACT_M, "the walker walked into the robot"


# ---------------------------------------------------------------- the doorway
def _doorway(model: str, ignore_share: float = 0.0) -> World:
    """Two rooms (12 m x 6 m in all) joined by a 1 m doorway at x 6.0-6.2, y 2.5-3.5; someone
    stands in it and the robot waits in front of it, facing it."""
    grid = room(12.0, 6.0)
    fill(grid, 6.0, 0.0, 6.2, 2.5)
    fill(grid, 6.0, 3.5, 6.2, 6.0)
    stander = PersonState(0, 6.1, 3.0, behaviour="stander")
    return _world(grid, (4.6, 3.0, 0.0), [stander], model, ignore_share=ignore_share)


@pytest.mark.parametrize("model", BACKENDS)
def test_a_person_in_a_doorway_steps_aside_when_asked(model: str) -> None:
    world = _doorway(model)
    p = world.crowd.people[0]
    _run(world, 2.0)
    assert math.hypot(p.x - 6.1, p.y - 3.0) < 0.1  # a stander stands until asked
    assert world.ask_aside() == [0]
    _run(world, 8.0)
    across = abs(p.y - world.y)  # the robot faces +x along y = 3.0
    assert across >= BODY_CONTACT_M + 0.2 or p.x < world.x, (p.x, p.y)
    assert p.moving < 0.05  # and stands there
    assert world.raycaster.clearance_at(p.x, p.y) >= PERSON_RADIUS_M - WALL_TOLERANCE_M
    # the doorway is now free for the robot: it drives through
    for _ in range(round(8.0 / DT_S)):
        world.move(DT_S, 0.4, 0.0)
        world.step(DT_S)
    assert world.x > 7.0, world.pose
    assert world.collisions == 0, world.collisions_by_kind


@pytest.mark.parametrize("model", BACKENDS)
def test_a_person_who_ignores_the_robot_stays_in_the_doorway(model: str) -> None:
    world = _doorway(model, ignore_share=1.0)
    p = world.crowd.people[0]
    assert world.ask_aside() == []
    _run(world, 8.0)
    assert math.hypot(p.x - 6.1, p.y - 3.0) < 0.1
    assert p.ignores is True


def test_unknown_people_model_is_a_clear_error() -> None:
    grid = room(4.0, 4.0)
    with pytest.raises(ValueError, match="people_model must be one of"):
        make_crowd("crowdsim", [], None, lambda x, y: 1.0, np.random.default_rng(0), None,
                   grid=grid, start=(2.0, 2.0, 0.0), robot_radius=ROBOT_RADIUS_M)
    with pytest.raises(ValueError, match="share of people who ignore"):
        _world(grid, (2.0, 2.0, 0.0), [], "simple", ignore_share=1.5)


def test_auto_picks_jupedsim_when_installed() -> None:
    grid = room(4.0, 4.0)
    crowd = make_crowd("auto", [], None, lambda x, y: 1.0, np.random.default_rng(0), None,
                       grid=grid, start=(2.0, 2.0, 0.0), robot_radius=ROBOT_RADIUS_M)
    assert type(crowd).__name__ == ("JpsCrowd" if HAVE_JPS else "Crowd")
