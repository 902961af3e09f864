"""The navigator among people who hear it: someone in its way steps aside when it says
"excuse me" (or does not), on the simulated clock.

The nav tests' kinematic simulator (``tests/nav/nav_sim.py``) drives the real nodes; its
people are moved here by a :class:`World`'s crowd, stepped on the simulated clock with the
robot's true pose, and the navigator's ``blocked_by_people`` event reaches
``World.ask_aside`` as it does in the world node.
"""

from __future__ import annotations

import asyncio
import contextlib

import pytest

from sage_robot.core import topics
from sage_robot.core.msgs import Event
from sage_robot.core.msgs.nav import NavigateGoal
from sage_robot.sim.lidar import LidarSpec
from sage_robot.sim.people import PersonState
from sage_robot.sim.world import World

from ..nav.nav_sim import running, settings_for, write_building
from ..nav.test_navigator import NARROW, REAL_TIMEOUT_S
from ..support.grids import draw
from .test_people_jps import BACKENDS

CROWD_STEP_S = 0.05  # the people are stepped this often (s of simulated time)
A, B = (1.5, 2.0, 0.0), (9.5, 2.0, 0.0)  # rooms at either end of NARROW's 1 m corridor
# Two 1 m corridors between the rooms: the lower one is where someone stands.
TWO_WAYS = """
######################
#......#######.......#
#....................#
#....................#
#......#######.......#
#......#######.......#
#....................#
#....................#
#......#######.......#
######################
"""
A2, B2 = (1.5, 1.5, 0.0), (9.5, 1.5, 0.0)


async def _people(clock, sim, world: World) -> None:
    while True:
        await clock.sleep(CROWD_STEP_S)
        world.x, world.y, world.theta = sim.pose
        world.step(CROWD_STEP_S)
        sim.people[:] = [[p.x, p.y] for p in world.crowd.people]


async def _drive(tmp_path, picture: str, start, goal, person_at, model: str, ignore_share: float,
                 wait_s: float):
    grid = draw(picture, 0.05, scale=10)
    path = write_building(tmp_path, grid, {"START": start, "GOAL": goal})
    world = World(grid, start, people=[PersonState(0, person_at[0], person_at[1], behaviour="stander")],
                  people_model=model, ignore_share=ignore_share,
                  lidar=LidarSpec(noise_fraction=0.0, noise_floor_m=0.0, dropout_probability=0.0))
    async with running(settings_for(path, "START", people_wait_s=wait_s), grid, start) as (bus, clock, sim):
        asked: list[list[int]] = []

        def hear(ev: Event) -> None:
            if ev.kind == "blocked_by_people":
                asked.append(world.ask_aside())

        bus.subscribe(topics.EVENTS, Event, hear, maxsize=100)
        sim.people[:] = [list(person_at)]
        crowd = asyncio.ensure_future(_people(clock, sim, world))
        try:
            handle = await bus.actions.send_goal(topics.NAVIGATE_TO, NavigateGoal(place="GOAL"))
            result = await asyncio.wait_for(handle.result(), REAL_TIMEOUT_S)
        finally:
            crowd.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await crowd
        return result, sim, asked


@pytest.mark.parametrize("model", BACKENDS)
async def test_the_robot_gets_past_someone_who_steps_aside(tmp_path, model: str) -> None:
    result, sim, asked = await _drive(tmp_path, NARROW, A, B, (5.25, 2.0), model, 0.0, wait_s=30.0)
    assert asked  # it asked...
    assert asked[0] == [0]  # ...and the person heard
    assert result.ok, result.message
    assert sim.collisions == 0


async def test_someone_who_does_not_step_aside_gets_a_true_reason(tmp_path) -> None:
    result, sim, asked = await _drive(tmp_path, NARROW, A, B, (5.25, 2.0), "simple", 1.0, wait_s=5.0)
    assert asked == [[]]  # asked once; nobody moved
    assert not result.ok
    # the true reason: something it watched stand in the way, no way round (the lidar cannot
    # tell a person who will not move from a box); not "the map is closed"
    assert "no way around" in result.message, result.message
    assert "on the map: there is no passage" not in result.message, result.message
    assert sim.collisions == 0


async def test_the_robot_takes_the_other_way_round_someone_who_does_not_move(tmp_path) -> None:
    result, sim, _ = await _drive(tmp_path, TWO_WAYS, A2, B2, (5.25, 1.5), "simple", 1.0, wait_s=5.0)
    assert result.ok, result.message
    assert max(y for _t, _x, y, _th in sim.truth) > 2.8  # by the upper corridor
    assert sim.collisions == 0
