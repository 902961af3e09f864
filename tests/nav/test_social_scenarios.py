"""Social behaviour (issue #20) on the bus: the real nodes driven by the kinematic simulator on
the simulated clock: keeping right in a 3 m corridor, slowing down past a person, pulling over
for two people coming head-on in a 1.8 m corridor. People are circles the test moves."""

from __future__ import annotations

import asyncio
import math

import numpy as np

from sage_robot.core import topics
from sage_robot.core.msgs import Event
from sage_robot.core.msgs.nav import NavigateGoal
from sage_robot.nav.social import SLOW_MPS

from ..support.grids import draw
from .nav_sim import PERSON_RADIUS_M, running, settings_for, write_building
from .test_navigator import GOAL_TOLERANCE_TRUTH_M, REAL_TIMEOUT_S

RES = 0.05
# 14 m long corridors; 0.5 m per character (interior y from 0.5 up).
CORRIDOR_3M = """
##############################
#............................#
#............................#
#............................#
#............................#
#............................#
#............................#
##############################
"""
WALK_STEP_S = 0.05  # the walkers move this often (simulated s)
WALKER_MPS = 0.8
WALKER_KEEP_M = 2 * PERSON_RADIUS_M + 0.05  # a walker stops rather than walk into the robot (m)


def _corridor(tmp_path, interior_m: float, start, goal):
    grid = draw(CORRIDOR_3M, RES, scale=10)
    grid.data[round((0.5 + interior_m) / RES):round(3.5 / RES), :] = 100  # narrower: fill from the top
    path = write_building(tmp_path, grid, {"START": start, "GOAL": goal})
    return grid, settings_for(path, "START")


def _events(bus) -> list[Event]:
    got: list[Event] = []
    bus.subscribe(topics.EVENTS, Event, got.append, maxsize=200)
    return got


async def _drive(bus, sim, goal):
    handle = await bus.actions.send_goal(topics.NAVIGATE_TO, NavigateGoal(place="GOAL"))
    result = await asyncio.wait_for(handle.result(), REAL_TIMEOUT_S)
    assert result.ok, result.message
    assert math.hypot(sim.pose[0] - goal[0], sim.pose[1] - goal[1]) <= GOAL_TOLERANCE_TRUTH_M
    assert sim.collisions == 0
    assert not sim.reversed_commands()


async def test_keeps_right_in_a_3m_corridor(tmp_path) -> None:
    centre = 2.0
    start, goal = (1.5, centre, 0.0), (13.0, centre, 0.0)
    grid, settings = _corridor(tmp_path, 3.0, start, goal)
    async with running(settings, grid, start) as (bus, _clock, sim):
        await _drive(bus, sim, goal)
        ys = np.array([y for _, x, y, _ in sim.truth if 4.0 < x < 10.0])
    assert len(ys)
    offset = centre - ys  # to the right of travel (east: south)
    assert offset.mean() > 0.3, offset.mean()


async def test_slows_down_passing_a_person(tmp_path) -> None:
    centre = 2.0
    start, goal = (1.5, centre, 0.0), (13.0, centre, 0.0)
    person = (7.0, 2.5)  # standing 0.5 m off the centre line, on the robot's left
    grid, settings = _corridor(tmp_path, 3.0, start, goal)
    async with running(settings, grid, start) as (bus, _clock, sim):
        events = _events(bus)
        sim.people.append(list(person))
        await _drive(bus, sim, goal)
    near = [c.linear_x for _, c, (x, y, _t) in sim.cmds if math.hypot(x - person[0], y - person[1]) < 1.2]
    far = [c.linear_x for _, c, (x, y, _t) in sim.cmds if math.hypot(x - person[0], y - person[1]) > 3.0]
    assert near
    assert max(near) <= SLOW_MPS + 1e-6
    assert max(far) > SLOW_MPS  # only near people
    assert sum(e.kind == "slowing_for_people" for e in events) >= 1


async def test_pulls_over_for_a_crowd_in_a_narrow_corridor(tmp_path) -> None:
    interior = 1.8  # y 0.5 .. 2.3
    centre = 0.5 + interior / 2
    start, goal = (1.5, centre, 0.0), (13.0, centre, 0.0)
    grid, settings = _corridor(tmp_path, interior, start, goal)
    lanes = (centre + 0.6, centre + 0.1)  # the walkers keep to their right (the robot's left)
    async with running(settings, grid, start) as (bus, clock, sim):
        events = _events(bus)
        handle = await bus.actions.send_goal(topics.NAVIGATE_TO, NavigateGoal(place="GOAL"))
        walkers: list[list[float]] = []
        started = False
        stalls = 0
        passing: list[tuple[float, float]] = []  # the robot's (y, speed) while a walker passes it
        while not handle.done and clock.now() < 120.0:
            await clock.sleep(WALK_STEP_S)
            if not started and sim.pose[0] > 3.0:  # two people, one a little behind the other
                started, walkers = True, [[11.0, lanes[0]], [11.8, lanes[1]]]
                sim.people.extend(walkers)
            for w in list(walkers):
                nx = w[0] - WALKER_MPS * WALK_STEP_S
                if math.hypot(nx - sim.pose[0], w[1] - sim.pose[1]) < WALKER_KEEP_M:
                    stalls += 1
                    continue
                w[0] = nx
                if abs(w[0] - sim.pose[0]) < 0.5:
                    passing.append((sim.pose[1], sim.cmd.linear_x))
                if w[0] < 1.0:  # out of the corridor
                    walkers.remove(w)
                    sim.people.remove(w)
        result = await asyncio.wait_for(handle.result(), REAL_TIMEOUT_S)
    assert result.ok, result.message
    assert sim.collisions == 0
    assert not sim.reversed_commands()
    assert any(e.kind == "pulling_over" for e in events), [e.kind for e in events]
    assert passing
    assert max(y for y, _v in passing) < centre - 0.3  # beside the right wall while they pass
    assert stalls == 0  # nobody had to wait for the robot
