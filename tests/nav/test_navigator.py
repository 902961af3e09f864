"""The navigation nodes on the bus, driven by a kinematic simulator on the SimClock."""

from __future__ import annotations

import asyncio
import itertools
import math

import yaml

from sage_robot.core import topics
from sage_robot.core.actions import GoalStatus
from sage_robot.core.msgs import Event, Pose2D, Text
from sage_robot.core.msgs.nav import NavigateFeedback, NavigateGoal, NavState, PlaceList, TourGoal
from sage_robot.nav.drive import SETTLE_NEAR_GOAL_M

from ..support.grids import draw
from ..support.waits import sim_until
from .nav_sim import running, settings_for, write_building

# Deterministic: the SimClock runs unpaced and the nodes' planning and filtering are offloaded
# in lockstep with it (Clock.offload), so a loaded machine takes longer but drives the same run.
# Wall-clock bounds (REAL_TIMEOUT_S) only stop a hung test.

# Two rooms joined by a corridor; 0.5 m per character.
NARROW = """
######################
#......#######.......#
#......#######.......#
#....................#
#....................#
#......#######.......#
#......#######.......#
######################
"""
WIDE = """
######################
#....................#
#....................#
#....................#
#....................#
#....................#
#....................#
######################
"""
A, B = (1.5, 2.0, 0.0), (9.5, 2.0, 0.0)
REAL_TIMEOUT_S = 120.0  # wall-clock bound per goal (a normal run takes 5-15 s)
GOAL_TOLERANCE_TRUTH_M = 0.4  # xy goal tolerance (0.25 m, on the estimate) + localization error


def _building(tmp_path, picture, **nav):
    grid = draw(picture, 0.05, scale=10)
    path = write_building(tmp_path, grid, {"ROOM_A": A, "ROOM_B": B})
    return grid, settings_for(path, "ROOM_A", **nav)


def _events(bus):
    got: list[Event] = []
    bus.subscribe(topics.EVENTS, Event, got.append, maxsize=100)
    return got


def _nav_states(bus, clock):
    """(simulated time, NavigateFeedback) of every NAV_STATE message, from subscription on."""
    got: list[tuple[float, NavigateFeedback]] = []
    bus.subscribe(topics.NAV_STATE, NavigateFeedback, lambda m: got.append((clock.now(), m)), maxsize=1000)
    return got


async def _go(bus, place):
    return await bus.actions.send_goal(topics.NAVIGATE_TO, NavigateGoal(place=place))


async def test_drives_to_a_place_by_alias(tmp_path) -> None:
    grid, settings = _building(tmp_path, WIDE)
    async with running(settings, grid, A) as (bus, clock, sim):
        events = _events(bus)
        nav_states = _nav_states(bus, clock)
        places = await bus.call(topics.PLACES, Text(""))
        assert isinstance(places, PlaceList)
        assert {p.name for p in places.places} == {"ROOM_A", "ROOM_B"}
        handle = await _go(bus, "room b")
        states = set()

        async def watch():
            async for fb in handle.feedback():
                states.add(fb.state)

        watcher = asyncio.ensure_future(watch())
        result = await asyncio.wait_for(handle.result(), REAL_TIMEOUT_S)
        await watcher
        assert result.ok, result.message
        assert result.value.succeeded
        assert result.value.place == "ROOM_B"
        x, y, _ = sim.pose
        assert math.hypot(x - B[0], y - B[1]) <= GOAL_TOLERANCE_TRUTH_M
        assert NavState.DRIVING in states
        assert any(e.kind == "arrived" and e.data == {"place": "ROOM_B"} for e in events)
        assert sim.collisions == 0
        assert not sim.reversed_commands()
        assert sim.cmds[-1][1].is_zero
        # NAV_STATE: latched IDLE first, every change, 1 Hz while driving, IDLE at the end
        kinds = [m.state for _, m in nav_states]
        assert kinds[0] is NavState.IDLE
        assert kinds[-1] is NavState.IDLE
        assert NavState.PLANNING in kinds
        driving = [(t, m) for t, m in nav_states if m.state is NavState.DRIVING]
        assert all(m.place == "ROOM_B" for _, m in driving)
        span = driving[-1][0] - driving[0][0]
        assert span > 5.0
        assert len(driving) >= int(span)  # at least one a second
        assert max(b[0] - a[0] for a, b in itertools.pairwise(driving)) <= 1.0 + 0.2
        assert any(m.distance_remaining_m > 1.0 for _, m in driving)
        n = len(nav_states)
        await clock.sleep(3.0)
        assert len(nav_states) == n  # idle: no repeats
        where = await bus.call(topics.WHERE_AM_I, Text(""))
        assert where.nearest_place == "ROOM_B"
        assert where.localized


async def test_waits_for_a_person_then_goes_on(tmp_path) -> None:
    grid, settings = _building(tmp_path, NARROW, people_wait_s=30.0)
    async with running(settings, grid, A) as (bus, clock, sim):
        events = _events(bus)
        sim.people.append([5.25, 2.0])  # standing in the 1 m corridor
        handle = await _go(bus, "ROOM_B")
        await asyncio.wait_for(
            sim_until(clock, lambda: any(e.kind == "blocked_by_people" for e in events), "the event", 60),
            REAL_TIMEOUT_S)
        assert handle.last_feedback.state in (NavState.WAITING_FOR_PEOPLE, NavState.RECOVERING)
        await clock.sleep(3.0)
        assert not handle.done  # still waiting, not aborted
        sim.people.clear()  # they step aside
        result = await asyncio.wait_for(handle.result(), REAL_TIMEOUT_S)
        assert result.ok, result.message
        assert sim.collisions == 0
        assert not sim.reversed_commands()


async def test_excuse_me_once_when_someone_steps_back_in(tmp_path) -> None:
    """Someone steps aside, then back in front of the robot: it waits again, quietly (a robot
    that says "excuse me" at every retry nags; issue #20 counted 263 on one benchmark)."""
    grid, settings = _building(tmp_path, NARROW, people_wait_s=30.0)
    async with running(settings, grid, A) as (bus, clock, sim):
        events = _events(bus)
        sim.people.append([5.25, 2.0])
        handle = await _go(bus, "ROOM_B")
        waits = lambda: sum(e.kind == "blocked_by_people" for e in events)  # noqa: E731
        await asyncio.wait_for(sim_until(clock, lambda: waits() == 1, "the first excuse me", 60),
                               REAL_TIMEOUT_S)
        sim.people.clear()  # they step aside ...
        start_x = sim.pose[0]
        await asyncio.wait_for(sim_until(clock, lambda: sim.pose[0] > start_x + 0.3, "driving on", 30),
                               REAL_TIMEOUT_S)
        sim.people.append([sim.pose[0] + 1.2, 2.0])  # ... and back in front of it
        await asyncio.wait_for(
            sim_until(clock, lambda: handle.last_feedback.state is NavState.WAITING_FOR_PEOPLE
                      and abs(sim.cmds[-1][1].linear_x) < 1e-9, "waiting again", 30),
            REAL_TIMEOUT_S)
        await clock.sleep(2.0)
        assert waits() == 1, [e.kind for e in events]
        sim.people.clear()
        result = await asyncio.wait_for(handle.result(), REAL_TIMEOUT_S)
        assert result.ok, result.message


async def test_goes_around_a_person_who_never_moves(tmp_path) -> None:
    grid, settings = _building(tmp_path, WIDE, people_wait_s=5.0)
    async with running(settings, grid, A) as (bus, _clock, sim):
        sim.people.append([5.25, 2.0])  # in the middle of a 3 m wide hall
        handle = await _go(bus, "ROOM_B")
        result = await asyncio.wait_for(handle.result(), REAL_TIMEOUT_S)
        assert result.ok, result.message
        assert sim.collisions == 0
        assert not sim.reversed_commands()
        closest = min(math.hypot(x - 5.25, y - 2.0) for _, x, y, _ in sim.truth)
        assert closest > 0.5 + 0.1  # body radii plus a margin


async def test_fully_blocked_corridor_aborts_with_a_reason(tmp_path) -> None:
    grid, settings = _building(tmp_path, NARROW, people_wait_s=3.0)
    async with running(settings, grid, A) as (bus, _clock, sim):
        events = _events(bus)
        sim.people.append([5.25, 2.0])
        handle = await _go(bus, "ROOM_B")
        result = await asyncio.wait_for(handle.result(), REAL_TIMEOUT_S)
        assert result.status is GoalStatus.ABORTED
        assert "blocked" in result.message
        assert "room b" in result.message
        # "excuse me" once, then wait: not again at every rung of the recovery ladder
        assert sum(e.kind == "blocked_by_people" for e in events) == 1, [e.kind for e in events]
        assert sim.collisions == 0
        assert not sim.reversed_commands()
        assert sim.cmds[-1][1].is_zero


async def test_cancel_stops_the_robot_and_preempt_switches_goal(tmp_path) -> None:
    grid, settings = _building(tmp_path, WIDE)
    async with running(settings, grid, A) as (bus, clock, sim):
        nav_states = _nav_states(bus, clock)
        first = await _go(bus, "ROOM_B")
        await clock.sleep(4.0)
        assert sim.cmds
        assert not sim.cmds[-1][1].is_zero
        reply = await bus.call(topics.CANCEL_NAV, Text(""))
        assert "navigate_to" in reply.data
        result = await asyncio.wait_for(first.result(), REAL_TIMEOUT_S)
        assert result.status is GoalStatus.CANCELED
        assert sim.cmds[-1][1].is_zero
        assert nav_states[-1][1].state is NavState.IDLE
        moved_at_cancel = sim.pose
        await clock.sleep(2.0)
        assert math.hypot(sim.pose[0] - moved_at_cancel[0], sim.pose[1] - moved_at_cancel[1]) < 0.05
        # preempt: a goal to B, then one back to A before B is reached
        to_b = await _go(bus, "ROOM_B")
        await clock.sleep(2.0)
        preempt_t = clock.now()
        to_a = await bus.actions.send_goal(topics.NAVIGATE_TO, NavigateGoal(pose=Pose2D(*A)))
        assert (await asyncio.wait_for(to_b.result(), REAL_TIMEOUT_S)).status is GoalStatus.PREEMPTED
        result = await asyncio.wait_for(to_a.result(), REAL_TIMEOUT_S)
        assert result.ok, result.message
        assert math.hypot(sim.pose[0] - A[0], sim.pose[1] - A[1]) <= GOAL_TOLERANCE_TRUTH_M
        assert not sim.reversed_commands()
        # the preempted goal's end does not mark the preempting one idle
        after = [m.state for t, m in nav_states if t >= preempt_t]
        active = after.index(NavState.PLANNING)  # the preempting goal starts
        assert NavState.IDLE not in after[active:-1], after
        assert after[-1] is NavState.IDLE, after


async def test_unknown_place_aborts_and_places_added_at_run_time_are_known(tmp_path) -> None:
    grid, settings = _building(tmp_path, WIDE)
    async with running(settings, grid, A) as (bus, clock, sim):
        result = await asyncio.wait_for((await _go(bus, "the moon base")).result(), REAL_TIMEOUT_S)
        assert result.status is GoalStatus.ABORTED
        assert "the moon base" in result.message
        assert "ROOM_B" in result.message
        # the web admin adds a place to the waypoints file and says so on EVENTS
        wp = tmp_path / "waypoints.yaml"
        data = yaml.safe_load(wp.read_text(encoding="utf-8"))
        data["places"].append({"name": "MOON_BASE", "pose": [5.0, 2.0, 0.0], "aliases": ["the moon base"]})
        wp.write_text(yaml.safe_dump(data), encoding="utf-8")
        bus.publish(topics.EVENTS, Event(clock.now(), "web", "places_changed", "places edited"))
        await clock.sleep(0.1)
        places = await bus.call(topics.PLACES, Text(""))
        assert "MOON_BASE" in {p.name for p in places.places}
        result = await asyncio.wait_for((await _go(bus, "the moon base")).result(), REAL_TIMEOUT_S)
        assert result.ok, result.message
        assert result.value.place == "MOON_BASE", result.message
        assert math.hypot(sim.pose[0] - 5.0, sim.pose[1] - 2.0) <= GOAL_TOLERANCE_TRUTH_M
        # a broken file is not taken: the places stay as they were
        wp.write_text("places: [oops", encoding="utf-8")
        bus.publish(topics.EVENTS, Event(clock.now(), "web", "places_changed", "places edited"))
        await clock.sleep(0.1)
        places = await bus.call(topics.PLACES, Text(""))
        assert {p.name for p in places.places} == {"ROOM_A", "ROOM_B", "MOON_BASE"}
        assert (await asyncio.wait_for((await _go(bus, "room a")).result(), REAL_TIMEOUT_S)).ok


async def test_tour_visits_in_order_and_resumes(tmp_path) -> None:
    grid, settings = _building(tmp_path, WIDE)
    async with running(settings, grid, A) as (bus, clock, sim):
        events = _events(bus)
        nav_states = _nav_states(bus, clock)
        handle = await bus.actions.send_goal(topics.TOUR, TourGoal(("ROOM_B", "ROOM_A"), 2.0, start_index=1))
        result = await asyncio.wait_for(handle.result(), REAL_TIMEOUT_S)
        assert result.ok
        assert result.value.succeeded
        assert result.value.completed == ("ROOM_A",)
        handle = await bus.actions.send_goal(topics.TOUR, TourGoal(("ROOM_B", "ROOM_A"), 2.0))
        result = await asyncio.wait_for(handle.result(), REAL_TIMEOUT_S)
        assert result.value.completed == ("ROOM_B", "ROOM_A"), result
        arrived = [e.data["place"] for e in events if e.kind == "arrived"]
        assert arrived == ["ROOM_A", "ROOM_B", "ROOM_A"]
        driven = [m.place for _, m in nav_states if m.state is NavState.DRIVING]
        assert {"ROOM_A", "ROOM_B"} <= set(driven)  # tour legs show on NAV_STATE too
        assert nav_states[-1][1].state is NavState.IDLE
        assert sim.collisions == 0
        assert not sim.reversed_commands()


async def test_settles_near_a_goal_someone_stands_on(tmp_path) -> None:
    grid, settings = _building(tmp_path, WIDE, people_wait_s=2.0)
    async with running(settings, grid, A) as (bus, _clock, sim):
        sim.people.append([B[0], B[1]])  # a visitor stands right on the spot
        result = await asyncio.wait_for((await _go(bus, "ROOM_B")).result(), REAL_TIMEOUT_S)
        assert result.ok, (result.message, sim.pose, B)
        assert "short" in result.value.reason
        assert math.hypot(sim.pose[0] - B[0], sim.pose[1] - B[1]) <= SETTLE_NEAR_GOAL_M + 0.2
        assert sim.collisions == 0
        assert not sim.reversed_commands()
