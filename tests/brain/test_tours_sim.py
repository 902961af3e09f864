"""The tour node on the simulated clock: a planned tour driven stop by stop, paused, resumed,
skipped and stopped (by its service, as the pages and the tool do); a visitor's "I like
robots and 3D printing" planned, said back and started on "yes" by the offline brain; and a
model (the scripted OpenAI-compatible server) planning and starting the same tour.

Navigation is a small stand-in at its bus seam (the ``navigate_to`` action, ``/amcl_pose``,
``arrived`` events) that drives straight at a fixed speed on the simulated clock; the tour
node, the bus, the clock, the map, the places and the brain's tools are the real ones.
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import AsyncIterator
from dataclasses import dataclass, field

import pytest

from sage_robot.brain.llm import LlmBrain
from sage_robot.brain.offline import OfflineBrain
from sage_robot.brain.robot import RobotLink
from sage_robot.brain.scripted import ScriptedServer, call, say
from sage_robot.brain.tools import ToolContext, ToolRegistry
from sage_robot.brain.tour_runner import TourNode
from sage_robot.core import topics
from sage_robot.core.actions import GoalContext
from sage_robot.core.bus import Bus
from sage_robot.core.clock import SimClock
from sage_robot.core.config import Settings
from sage_robot.core.mapio import read_map
from sage_robot.core.msgs import Event, Pose2D, PoseWithCovariance, Text
from sage_robot.core.msgs.nav import NavigateFeedback, NavigateGoal, NavigateResult, NavState
from sage_robot.core.msgs.tour import TourCommand, TourPhase, TourPlan, TourRequest, TourState
from sage_robot.core.node import NodeContext
from sage_robot.core.paths import package_data, waypoints_yaml
from sage_robot.core.places import Places, load_places

from ..support.waits import sim_step_until

DRIVE_MPS = 1.0  # the stand-in's speed
STEP_S = 0.5  # its control period, and the test's clock step (simulated s)
COV = (0.01, 0.0, 0.0, 0.0, 0.01, 0.0, 0.0, 0.0, 0.01)
WALL_S = 20.0  # bound on each awaited service call (wall s)


@dataclass
class StraightNav:
    """navigate_to on the simulated clock: straight at DRIVE_MPS, arrival event, pose out."""

    bus: Bus
    places: Places
    x: float = 0.0
    y: float = 0.0
    goals: list[str] = field(default_factory=list)
    unreachable: set[str] = field(default_factory=set)

    def serve(self) -> StraightNav:
        self.bus.actions.serve(topics.NAVIGATE_TO, self._navigate)
        self._pose()
        return self

    def _pose(self) -> None:
        pose = PoseWithCovariance(self.bus.clock.now(), "map", Pose2D(self.x, self.y), COV)
        self.bus.publish(topics.AMCL_POSE, pose)

    async def _navigate(self, goal: NavigateGoal, ctx: GoalContext) -> NavigateResult:
        self.goals.append(goal.place)
        if goal.place in self.unreachable:
            await self.bus.clock.sleep(STEP_S)
            return NavigateResult(False, goal.place, "the corridor is blocked")
        target = self.places.get(goal.place).pose
        while (d := math.hypot(target.x - self.x, target.y - self.y)) > 1e-6:
            ctx.feedback(NavigateFeedback(NavState.DRIVING, goal.place, d, d / DRIVE_MPS))
            await self.bus.clock.sleep(STEP_S)
            step = min(1.0, DRIVE_MPS * STEP_S / d)
            self.x += step * (target.x - self.x)
            self.y += step * (target.y - self.y)
            self._pose()
        arrived = Event(self.bus.clock.now(), "navigator", "arrived", "", {"place": goal.place})
        self.bus.publish(topics.EVENTS, arrived)
        return NavigateResult(True, goal.place)


@dataclass
class Rig:
    clock: SimClock
    bus: Bus
    nav: StraightNav
    node: TourNode
    states: list[TourState]
    said: list[str]

    @property
    def state(self) -> TourState:
        return self.states[-1]

    async def command(self, command: str, *places: str) -> TourState:
        call = self.bus.call(topics.TOUR_CONTROL, TourCommand(command, places))
        reply = await asyncio.wait_for(call, WALL_S)
        assert isinstance(reply, TourState)
        return reply

    async def until(self, cond: object, what: str, timeout_s: float = 300.0) -> None:
        await sim_step_until(self.clock, cond, what, timeout_s, step_s=STEP_S)  # type: ignore[arg-type]


@pytest.fixture
async def rig() -> AsyncIterator[Rig]:
    clock = SimClock()
    bus = Bus(clock)
    settings = Settings()
    places = load_places(waypoints_yaml(settings))
    dock = places.get("DOCKING_STATION").pose
    nav = StraightNav(bus, places, dock.x, dock.y).serve()
    node = TourNode(NodeContext(bus, clock, settings))
    states: list[TourState] = []
    said: list[str] = []
    bus.subscribe(topics.TOUR_STATE, TourState, states.append, maxsize=100)
    bus.subscribe(topics.SAY, Text, lambda m: said.append(m.data), maxsize=100)
    await node.setup()
    r = Rig(clock, bus, nav, node, states, said)
    await r.until(lambda: states, "the latched idle state")
    try:
        yield r
    finally:
        await node.teardown()
        await node._close()


async def test_a_two_stop_tour_pauses_resumes_skips_and_stops(rig: Rig) -> None:
    started = await rig.command("start", "the cafe", "clean room")
    assert started.ok
    assert started.stops == ("GUELLY_DELLY", "CLEAN_ROOM")
    assert started.titles[0] == "Guelly Delly café"
    await rig.until(lambda: rig.nav.goals == ["GUELLY_DELLY"] and rig.nav.x < 60, "driving to the café")

    paused = await rig.command("pause")
    assert "I will wait here. Say resume when you want to go on." in rig.said  # a page's pause is said
    assert paused.phase is TourPhase.PAUSED
    assert paused.index == 0
    where = (rig.nav.x, rig.nav.y)
    rig.clock.advance_to(rig.clock.now() + 20.0)
    await rig.until(lambda: rig.clock.now() > 0, "a step")
    assert (rig.nav.x, rig.nav.y) == where  # paused: no goal runs
    assert (await rig.command("pause")).reason == "the tour is already paused"

    resumed = await rig.command("resume")
    assert resumed.phase is TourPhase.DRIVING
    await rig.until(lambda: rig.state.phase is TourPhase.AT_STOP, "arrival at the café")
    assert rig.state.visited == ("GUELLY_DELLY",)
    assert rig.nav.goals == ["GUELLY_DELLY", "GUELLY_DELLY"]  # the same stop again after the pause

    skipped = await rig.command("skip")  # the rest of the dwell: go on at once
    assert skipped.index == 1
    assert skipped.phase is TourPhase.DRIVING
    await rig.until(lambda: rig.nav.goals[-1:] == ["CLEAN_ROOM"], "on the way to the clean room")
    assert any(s.startswith("Next, the Clean Room") for s in rig.said), rig.said

    stopped = await rig.command("stop")
    assert stopped.phase is TourPhase.STOPPED
    assert stopped.reason == "stopped on request"
    assert rig.state.visited == ("GUELLY_DELLY",)
    assert (await rig.command("resume")).reason == "no tour is running"
    assert not (await rig.command("teleport")).ok


async def test_a_tour_runs_to_the_end_skipping_what_it_can_not_reach(rig: Rig) -> None:
    rig.nav.unreachable.add("CLEAN_ROOM")
    await rig.command("start", "GUELLY_DELLY", "CLEAN_ROOM", "3D_PRINTING_LAB")
    await rig.until(lambda: rig.state.phase is TourPhase.DONE, "the end of the tour", timeout_s=600.0)
    assert rig.state.visited == ("GUELLY_DELLY", "3D_PRINTING_LAB")
    assert rig.state.skipped == ("CLEAN_ROOM",)
    assert any("can not get to the Clean Room: the corridor is blocked" in s for s in rig.said), rig.said
    assert rig.said[-1] == "That was the last stop of our tour. Thank you for visiting!"


async def test_a_goal_ended_by_someone_else_pauses_the_tour(rig: Rig) -> None:
    await rig.command("start", "GUELLY_DELLY", "CLEAN_ROOM")
    await rig.until(lambda: rig.bus.actions.active(topics.NAVIGATE_TO) is not None, "a leg")
    handle = rig.bus.actions.active(topics.NAVIGATE_TO)
    assert handle is not None
    handle.request_cancel()  # the e-stop, the face's Stop, the operator's Cancel
    await rig.until(lambda: rig.state.phase is TourPhase.PAUSED, "the tour paused")
    assert "navigation was stopped" in rig.state.reason
    skipped = await rig.command("skip")  # skipping while paused goes on to the next stop
    assert skipped.skipped == ("GUELLY_DELLY",)
    assert skipped.phase is TourPhase.DRIVING
    await rig.until(lambda: rig.state.phase is TourPhase.AT_STOP, "at the clean room")
    assert rig.state.stops[rig.state.index] == "CLEAN_ROOM"


async def test_the_visitor_plan_is_said_and_started_on_yes(rig: Rig) -> None:
    """On the map's path lengths (the latched /map), from where the robot stands."""
    grid = read_map(package_data("maps", "campus", "map.yaml"))
    rig.bus.declare(topics.MAP, latched=True)
    rig.bus.publish(topics.MAP, grid)
    await rig.until(lambda: rig.node.routes is not None, "the route table", timeout_s=60.0)
    robot = RobotLink(rig.bus, waypoints_yaml(Settings()))
    brain = OfflineBrain(ToolRegistry(ToolContext(robot, Settings())), clock=rig.clock)

    offer = await asyncio.wait_for(brain.respond("I like robots and 3D printing"), WALL_S)
    assert offer.reply.startswith("I can show you the ")
    assert "2 stops, about " in offer.reply
    assert offer.reply.endswith("Shall we start?")
    plan = offer.tool_calls[0]
    assert plan.name == "plan_tour"
    assert plan.result.data["distances"] == "map"
    assert set(plan.result.data["stops"]) == {"VALPO_ROBOTICS", "3D_PRINTING_LAB"}
    assert rig.nav.goals == []  # nothing moves before the visitor agrees

    start = await asyncio.wait_for(brain.respond("yes please"), WALL_S)
    assert start.reply.startswith("Wonderful, let us go! First, the ")
    assert start.tool_calls[0].arguments == {"places": plan.result.data["stops"]}
    await rig.until(lambda: rig.nav.goals, "the first leg")
    assert rig.nav.goals == plan.result.data["stops"][:1]

    paused = await asyncio.wait_for(brain.respond("pause the tour"), WALL_S)
    assert paused.reply.startswith("Sure, I will wait here")
    assert rig.state.phase is TourPhase.PAUSED
    ended = await asyncio.wait_for(brain.respond("stop the tour"), WALL_S)
    assert ended.reply.startswith("All right, the tour ends here")
    final = rig.states[-1]
    assert final.phase is TourPhase.STOPPED
    assert not any("wait here" in s or "tour ends here" in s for s in rig.said)  # the brain's reply says it
    await robot.close()


async def test_a_model_plans_says_and_starts_the_same_tour(rig: Rig) -> None:
    """With an LLM: plan_tour with the visitor's words, then start_tour with the plan's stops
    as its places (the OpenAI-compatible server on loopback plays the model)."""
    plan = await rig.bus.call(topics.TOUR_PLAN, TourRequest("labs", budget_s=600.0))
    assert isinstance(plan, TourPlan)
    assert plan.ok
    stops = [s.name for s in plan.stops]
    async with ScriptedServer() as server:
        server.add(call(("plan_tour", {"interests": "labs", "minutes": 10})), say("Shall we start?"))
        server.add(call(("start_tour", {"places": stops})), say("Follow me!"))
        settings = Settings.model_validate({"llm": {"base_url": server.base_url, "timeout_s": 5.0}})
        robot = RobotLink(rig.bus, waypoints_yaml(settings))
        brain = LlmBrain(settings, ToolRegistry(ToolContext(robot, settings)), rig.clock)
        try:
            first = await asyncio.wait_for(brain.respond("I have ten minutes, show me the labs"), WALL_S)
            planned = first.tool_calls[0]
            assert planned.name == "plan_tour"
            assert planned.result.data["stops"] == stops
            assert planned.result.data["minutes"] <= 10
            assert rig.nav.goals == []
            second = await asyncio.wait_for(brain.respond("yes, let's go"), WALL_S)
            started = second.tool_calls[0]
            assert started.name == "start_tour"
            assert started.result.data["stops"] == stops  # the plan's order is kept
            await rig.until(lambda: rig.nav.goals, "the first leg")
            assert rig.state.stops == tuple(stops)
            assert rig.nav.goals == stops[:1]
        finally:
            await robot.close()
