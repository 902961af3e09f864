"""A tiny floor like the TurtleBot3 sandbox (issue #20): at most 1.45 m of floor between pillars
and walls, every spot within 3.5 m of every goal. The robot used to settle "short: someone is
standing at the spot" wherever it stopped near a goal, with nobody there; it must reach its
goals through the gaps it fits, and when it cannot, say truly why. The maps are drawn here, so
the tests run without the real maps; all on the simulated clock."""

from __future__ import annotations

import asyncio
import math

import numpy as np
import pytest

from sage_robot.core import topics
from sage_robot.core.msgs import OccupancyGrid
from sage_robot.core.msgs.nav import NavigateGoal
from sage_robot.nav.drive import SETTLE_NEAR_GOAL_M

from ..support.grids import FREE, WALL, blank, fill, room
from .nav_sim import running, settings_for, write_building
from .test_navigator import GOAL_TOLERANCE_TRUTH_M, REAL_TIMEOUT_S

RES = 0.05
BESIDE_THE_PERSON_M = 1.0  # a robot stopped for someone on its goal stands this close to it (m)


def _world_copy(g: OccupancyGrid) -> OccupancyGrid:
    return OccupancyGrid(g.stamp, g.frame_id, g.resolution, g.origin, g.data.copy())


async def _drive(tmp_path, mapped, world, start, goal, **nav):
    path = write_building(tmp_path, mapped, {"START": start, "GOAL": goal})
    settings = settings_for(path, "START", **nav)
    async with running(settings, world, start) as (bus, _clock, sim):
        handle = await bus.actions.send_goal(topics.NAVIGATE_TO, NavigateGoal(place="GOAL"))
        result = await asyncio.wait_for(handle.result(), REAL_TIMEOUT_S)
        return result, sim


async def test_nobody_at_the_goal_is_never_someone_standing_at_the_spot(tmp_path) -> None:
    # A floor 1.4 m wide and 5 m long; in the world (not on the map) a box closes it 1.5 m
    # before the goal. The robot stands within SETTLE_NEAR_GOAL_M of the goal with nobody about:
    # it used to settle there, "stopped 3.0 m short: someone is standing at the spot".
    mapped = room(5.2, 1.5, RES)
    world = _world_copy(mapped)
    fill(world, 2.7, 0.0, 3.1, 1.5, WALL)  # the unmapped box, wall to wall
    start, goal = (1.6, 0.75, 0.0), (4.6, 0.75, 0.0)
    result, sim = await _drive(tmp_path, mapped, world, start, goal, people_wait_s=3.0)
    msg = result.message or str(getattr(result.value, "reason", ""))
    assert not result.ok, msg
    for false in ("standing", "someone", "people"):
        assert false not in msg, msg
    assert "not on the map" in msg, msg
    assert math.hypot(sim.pose[0] - goal[0], sim.pose[1] - goal[1]) < SETTLE_NEAR_GOAL_M  # near the goal
    assert sim.collisions == 0
    assert not sim.reversed_commands()


async def test_a_tiny_floor_is_driven_through_the_gap_the_robot_fits(tmp_path) -> None:
    # A pillar in a 2.4 m deep room: 0.55 m below it (the robot is 0.5 m wide: the shortest way,
    # with 2.5 cm to spare each side), 0.8 m above it. As in the sandbox, where the robot stopped
    # for good (or scraped the wall) in such a gap.
    mapped = room(5.0, 2.5, RES)
    fill(mapped, 2.2, 0.6, 2.8, 1.6, WALL)  # the pillar: the gap below it is y 0.05..0.6
    start, goal = (0.8, 0.45, 0.0), (4.2, 0.45, 0.0)
    result, sim = await _drive(tmp_path, mapped, _world_copy(mapped), start, goal, people_wait_s=3.0)
    assert result.ok, result.message
    assert not result.value.reason, result.value.reason  # arrived, not "stopped ... short"
    assert math.hypot(sim.pose[0] - goal[0], sim.pose[1] - goal[1]) <= GOAL_TOLERANCE_TRUTH_M
    assert sim.collisions == 0
    past_pillar = [y for _, x, y, _ in sim.truth if 2.2 < x < 2.8]
    assert past_pillar
    assert min(past_pillar) > 1.6  # the way above the pillar, 0.8 m wide
    assert not sim.reversed_commands()


def _diagonal_channel(width_m: float) -> OccupancyGrid:
    """Two rooms joined by a channel ``width_m`` wide at 45 degrees to the grid: its walls are
    cell staircases, as the sandbox's hexagon and willow-2010's diagonal wall."""
    g = blank(120, 120, RES, value=WALL)  # 6 m x 6 m of rock
    rows, cols = np.indices(g.data.shape)
    x, y = (cols + 0.5) * RES, (rows + 0.5) * RES
    rooms = ((x > 0.3) & (x < 2.0) & (y > 0.3) & (y < 2.0)) | ((x > 4.0) & (x < 5.7) & (y > 4.0) & (y < 5.7))
    across, along = (x - y) / math.sqrt(2.0), (x + y) / math.sqrt(2.0)
    g.data[rooms | ((np.abs(across) < width_m / 2) & (along > 1.5) & (along < 7.0))] = FREE
    return g


@pytest.mark.parametrize("width_m", [0.7, 0.8])
async def test_a_diagonal_channel_the_robot_fits_is_passed(tmp_path, width_m) -> None:
    # robot width + 0.2 m (and a little more) between two diagonal walls: passed, slowly. The
    # lidar's hits on a staircase wall land in its notches, and each wall grew a cell for the
    # forward check: the robot stopped at the channel's mouth, "blocked by an obstacle that is
    # not on the map" (willow-2010 legs 5-6, the sandbox).
    g = _diagonal_channel(width_m)
    start, goal = (1.0, 1.0, 0.0), (5.0, 5.0, 0.0)
    result, sim = await _drive(tmp_path, g, _world_copy(g), start, goal, people_wait_s=3.0)
    assert result.ok, result.message
    assert not result.value.reason, result.value.reason
    assert math.hypot(sim.pose[0] - goal[0], sim.pose[1] - goal[1]) <= GOAL_TOLERANCE_TRUTH_M
    assert sim.collisions == 0
    assert not sim.reversed_commands()


def test_goal_taken_counts_what_stands_on_the_goal_not_the_walls() -> None:
    from sage_robot.nav.blockers import goal_taken
    from sage_robot.nav.costmap import Costmap

    cm = Costmap.from_grid(room(5.0, 2.5, RES), 0.25, 0.55, 3.0)
    goal = (4.5, 1.25)  # 0.45 m from the east wall's face
    angles = np.linspace(-0.3, 0.3, 61)
    # the wall itself, seen from a pose 7 cm off (localization): hits in front of the mapped wall
    cm.update_scan((0.93, 1.25, 0.0), angles, (4.95 - 1.0) / np.cos(angles), 12.0)
    assert cm.obstacles.any()
    assert goal_taken(cm, goal) is None  # hits on a mapped wall are that wall, not someone
    legs = np.array([-0.03, 0.03])  # a person's legs 0.2 m before the goal
    cm.update_scan((1.0, 1.25, 0.0), legs, np.full(2, 3.3), 12.0)
    size = goal_taken(cm, goal)
    assert size is not None
    assert size <= 0.6
    assert goal_taken(cm, (2.0, 1.25)) is None  # nothing on a goal elsewhere



@pytest.mark.parametrize(("start", "goal"), [
    ((-1.925, 0.675, 0.0), (-0.525, 1.575, 0.0)),  # between a pillar and the hexagon's wall
    ((-1.09, -1.61, 2.66), (-1.925, 0.675, 0.0)),  # from where the 50-leg bench stopped for good
])
async def test_the_sandboxs_bending_gaps_are_driven_through_their_middle(tmp_path, shared_data, start,
                                                                        goal) -> None:
    # The real sandbox (no people): its gaps between a pillar and the wall are 0.85 m wide and
    # bend. The scan's hits on the round pillar and the diagonal wall cost almost the same all
    # across such a gap (240 in its middle, 248 at its sides); with one flat weight for a narrow
    # cell the path hugged the inside of the bend, 14 cm off the middle, where the controller
    # and the collision guard stopped the robot for good ("I could not get past (-1.6, 1.0),
    # nothing there moved"): 8 of the bench's 19 stops in 50 legs.
    from sage_robot.core.mapio import read_map

    grid = read_map(shared_data("maps/tb3-sandbox/tb3_sandbox.yaml"))
    result, sim = await _drive(tmp_path, grid, _world_copy(grid), start, goal, people_wait_s=3.0)
    assert result.ok, result.message
    assert not result.value.reason, result.value.reason
    assert math.hypot(sim.pose[0] - goal[0], sim.pose[1] - goal[1]) <= GOAL_TOLERANCE_TRUTH_M
    assert sim.collisions == 0


async def test_a_person_seen_between_pillars_does_not_flip_the_plan_for_good(tmp_path, shared_data) -> None:
    # The real sandbox, someone standing for good 0.44 m from the goal (place 5 of the bench).
    # Driving there from place 4, the pillars hide the person from one pose and show them from
    # the next; a route they marked anywhere was dropped at once, so the plan flipped every
    # second between three routes (3.5 m west, 5.6 m south, 7.2 m round the east) and the robot
    # gave up 2.5 m from its start, "blocked ... I found no way around it". The path is now
    # dropped only when it is blocked within SWITCH_BLOCKED_AHEAD_M (or a fresh plan is much
    # shorter): the robot gets there, beside the person.
    from sage_robot.core.mapio import read_map

    grid = read_map(shared_data("maps/tb3-sandbox/tb3_sandbox.yaml"))
    start, goal = (0.575, -0.375, 0.0), (-1.925, 0.675, 0.0)
    path = write_building(tmp_path, grid, {"START": start, "GOAL": goal})
    settings = settings_for(path, "START", people_wait_s=5.0)
    async with running(settings, _world_copy(grid), start) as (bus, _clock, sim):
        sim.people.append([-1.9, 0.24])
        handle = await bus.actions.send_goal(topics.NAVIGATE_TO, NavigateGoal(place="GOAL"))
        result = await asyncio.wait_for(handle.result(), REAL_TIMEOUT_S)
    assert result.ok, result.message
    # (since session 20 the robot hugs its path round the pillars and reaches the goal itself,
    # beside the person; before, it settled short of it)
    reason = result.value.reason
    assert not reason or "standing at the spot" in reason, reason
    assert math.hypot(sim.pose[0] - goal[0], sim.pose[1] - goal[1]) < BESIDE_THE_PERSON_M
    assert sim.collisions == 0


async def test_a_mapped_table_leg_is_not_a_persons_leg(tmp_path) -> None:
    # The collision guard keeps the body 0.24 m from returns that look like a person's legs
    # (the body around them is not seen). A table's legs look the same to the lidar: those on
    # the map (willow-full's furniture), or beside its unknown cells, keep the ordinary 2 cm,
    # or the robot would be held in every office (five timeouts in nine legs there).
    from sage_robot.core.msgs import LaserScan

    mapped = room(5.0, 2.5, RES)
    fill(mapped, 2.0, 1.5, 2.1, 1.6, WALL)  # a table leg on the map
    world = _world_copy(mapped)
    fill(world, 2.0, 0.8, 2.1, 0.9, WALL)  # one that is not: to the guard, someone's leg
    start = (1.0, 1.25, 0.0)
    path = write_building(tmp_path, mapped, {"START": start, "GOAL": (4.5, 1.25, 0.0)})
    async with running(settings_for(path, "START"), world, start) as (bus, clock, sim):
        scans: list[LaserScan] = []
        bus.subscribe(topics.SCAN, LaserScan, scans.append)
        nav = sim.nodes[2]
        await clock.sleep(1.0)
        assert scans
        base, legs = nav._scan_base, nav._scan_legs
        assert legs is not None
        assert len(legs) == len(base)
        x, y = base[:, 0] + start[0], base[:, 1] + start[1]  # the robot faces +x at its start
        at_table = np.hypot(x - 2.05, y - 1.55) < 0.1
        at_unmapped = np.hypot(x - 2.05, y - 0.85) < 0.1
        assert at_table.any()
        assert at_unmapped.any()
        assert not legs[at_table].any()
        assert legs[at_unmapped].all()
