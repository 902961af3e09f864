"""Someone stands in a doorway and does not step aside when the robot asks: it reroutes by
another way when there is one, and gives a true reason when there is none. The real
navigation nodes, driven by the kinematic simulator on the simulated clock."""

from __future__ import annotations

import asyncio

from sage_robot.core import topics
from sage_robot.core.actions import GoalStatus
from sage_robot.core.msgs import Event
from sage_robot.core.msgs.nav import NavigateGoal

from ..support.grids import draw
from .nav_sim import running, settings_for, write_building
from .test_navigator import GOAL_TOLERANCE_TRUTH_M, REAL_TIMEOUT_S

# Two rooms joined by two 1 m corridors, the southern one shorter for the robot; 0.5 m per
# character, the bottom row at y = 0.
TWO_WAYS = """
######################
#......#######.......#
#....................#
#....................#
#......#######.......#
#......#######.......#
#......#######.......#
#......#######.......#
#....................#
#....................#
#......#######.......#
######################
"""
A, B = (1.5, 1.5, 0.0), (9.5, 1.5, 0.0)
DOORWAY = [7.0, 1.5]  # in the southern corridor's west end
PEOPLE_WAIT_S = 5.0


def _building(tmp_path, picture: str):
    grid = draw(picture, 0.05, scale=10)
    path = write_building(tmp_path, grid, {"ROOM_A": A, "ROOM_B": B})
    return grid, settings_for(path, "ROOM_A", people_wait_s=PEOPLE_WAIT_S)


async def test_reroutes_by_the_other_corridor_around_someone_who_stays(tmp_path) -> None:
    grid, settings = _building(tmp_path, TWO_WAYS)
    async with running(settings, grid, A) as (bus, _clock, sim):
        events: list[Event] = []
        bus.subscribe(topics.EVENTS, Event, events.append, maxsize=200)
        sim.people.append(list(DOORWAY))  # never steps aside
        handle = await bus.actions.send_goal(topics.NAVIGATE_TO, NavigateGoal(place="ROOM_B"))
        result = await asyncio.wait_for(handle.result(), REAL_TIMEOUT_S)
    assert result.ok, result.message
    x, y, _ = sim.pose
    assert abs(x - B[0]) + abs(y - B[1]) <= 2 * GOAL_TOLERANCE_TRUTH_M
    assert max(py for _, _px, py, _ in sim.truth) > 4.0, "it did not take the northern corridor"
    assert sim.collisions == 0
    assert not sim.reversed_commands()


async def test_no_other_way_says_a_person_blocks_it(tmp_path) -> None:
    one_way = TWO_WAYS.replace("#....................#\n#....................#\n#......#######.......#\n"
                               "#......#######.......#\n#......#######.......#\n#......#######.......#\n",
                               "#......#######.......#\n#......#######.......#\n#......#######.......#\n"
                               "#......#######.......#\n#......#######.......#\n#......#######.......#\n", 1)
    assert one_way != TWO_WAYS
    grid, settings = _building(tmp_path, one_way)
    async with running(settings, grid, A) as (bus, _clock, sim):
        events: list[Event] = []
        bus.subscribe(topics.EVENTS, Event, events.append, maxsize=200)
        sim.people.append(list(DOORWAY))
        handle = await bus.actions.send_goal(topics.NAVIGATE_TO, NavigateGoal(place="ROOM_B"))
        result = await asyncio.wait_for(handle.result(), REAL_TIMEOUT_S)
    assert result.status is GoalStatus.ABORTED
    # A person standing still and a box of their size look alike to a lidar: the reason says
    # both, and that it watched them (not "an obstacle" alone, not "people" alone).
    assert "someone standing still" in result.message, result.message
    assert "did not move" in result.message, result.message
    assert sum(e.kind == "blocked_by_people" for e in events) == 1, [e.kind for e in events]
    assert sim.collisions == 0
