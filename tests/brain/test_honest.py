"""Honest replies: the brain says "follow me" only when a goal was really taken.

The real brain node on a real Bus, with the fake navigator of ``conftest``: the e-stop
(latched ``/sage/estop``), the battery, localization health and the navigator's own state
decide whether a drive or a tour starts, and the reply (offline) or the tool result (LLM)
says what really happens.
"""

from __future__ import annotations

import asyncio
import datetime as dt
import json
from typing import Any

import pytest

from sage_robot.brain.node import BrainNode
from sage_robot.brain.readiness import DOCK, ESTOP_LINE, Readiness, Refusal
from sage_robot.brain.scripted import ScriptedServer, call, say
from sage_robot.core import topics
from sage_robot.core.actions import ActionAborted, GoalContext
from sage_robot.core.bus import Bus
from sage_robot.core.clock import SimClock
from sage_robot.core.config import Settings
from sage_robot.core.msgs import BatteryState, EStopState, Text
from sage_robot.core.msgs.nav import LocalizationHealth, NavigateFeedback, NavigateGoal, NavState
from sage_robot.core.node import NodeContext
from sage_robot.core.paths import package_data

from .conftest import WAIT_S, FakeNav, seed_places, until

pytestmark = pytest.mark.filterwarnings("ignore::ResourceWarning")

OFFLINE = {"nav": {"waypoints": str(package_data("brain", "places.yaml"))}}


async def start(bus: Bus, settings: dict[str, Any] | None = None) -> BrainNode:
    node = BrainNode(NodeContext(bus, bus.clock, Settings.model_validate(settings or OFFLINE)))
    await node.setup()
    return node


async def stop(node: BrainNode) -> None:
    await node.teardown()
    await node._close()


async def ask(bus: Bus, text: str) -> str:
    handle = await bus.actions.send_goal(topics.CONVERSE, Text(text))
    result = await asyncio.wait_for(handle.result(), WAIT_S)
    assert result.ok, result
    return str(result.value.data)


def estop(bus: Bus, engaged: bool) -> None:
    """As the web teleop does: latched, published on every change."""
    bus.declare(topics.ESTOP, EStopState, latched=True)
    bus.publish(topics.ESTOP, EStopState(engaged=engaged, by="operator" if engaged else ""))


def battery(bus: Bus, fraction: float) -> None:
    bus.publish(topics.BATTERY, BatteryState(0.0, 14.0, fraction))


async def settle() -> None:
    """Let the node's subscription tasks take what was just published."""
    for _ in range(5):
        await asyncio.sleep(0)


# ---------------------------------------------------------------- e-stop


async def test_estop_engaged_refuses_to_drive_and_released_drives() -> None:
    bus = Bus()
    nav = FakeNav(bus, seed_places()).serve()
    estop(bus, True)
    node = await start(bus)
    try:
        reply = await ask(bus, "take me to the cafe")
        assert reply == ESTOP_LINE
        assert "emergency stop" in reply
        assert "follow me" not in reply.lower()
        assert "emergency stop" in await ask(bus, "give me a tour")
        assert "emergency stop" in await ask(bus, "where are you going?")
        where = await ask(bus, "where is the clean room")
        assert "emergency stop" in where
        assert "Shall I take you there" not in where
        assert "follow me" not in (await ask(bus, "yes")).lower()
        await asyncio.sleep(0.05)
        assert nav.goals == []
        assert nav.tours == []  # no goal was ever sent
        estop(bus, False)
        assert await ask(bus, "take me to the cafe") == "Sure, follow me to the Guelly Delly café!"
        await until(lambda: nav.goals == ["GUELLY_DELLY"])
        assert (await ask(bus, "where are you going")).startswith("I am on my way to the Guelly Delly")
    finally:
        await stop(node)


async def test_estop_engaged_while_driving_is_what_the_robot_says_it_is_doing() -> None:
    bus = Bus()
    nav = FakeNav(bus, seed_places()).serve()
    node = await start(bus)
    try:
        await ask(bus, "take me to the clean room")
        await until(lambda: nav.goals)
        estop(bus, True)
        await settle()
        reply = await ask(bus, "what are you doing")
        assert reply.startswith("I am stopped: the emergency stop is on.")
        assert "on my way to the Clean Room" in reply
    finally:
        await stop(node)


async def test_llm_tool_result_carries_the_estop_refusal() -> None:
    async with ScriptedServer() as server:
        server.add(call(("set_goal", {"location": "the cafe"})), say("I can not move right now."))
        bus = Bus()
        nav = FakeNav(bus, seed_places()).serve()
        estop(bus, True)
        node = await start(bus, {**OFFLINE, "llm": {"base_url": server.base_url, "max_retries": 0}})
        node.brain._today = lambda: dt.date(2026, 1, 1)  # type: ignore[attr-defined]
        try:
            await ask(bus, "take me to the cafe")
            fed = [m for m in server.requests[1]["messages"] if m["role"] == "tool"]
            content = json.loads(fed[0]["content"])
            assert content == {"error": ESTOP_LINE, "goal_started": False, "refused": "estop"}
            system = server.requests[0]["messages"][0]["content"]
            assert "Safety status: emergency stop ENGAGED by operator" in system
            assert "goal_started true" in system
            assert nav.goals == []
        finally:
            await stop(node)


# ---------------------------------------------------------------- battery


async def test_critical_battery_goes_only_to_the_dock() -> None:
    bus = Bus()
    nav = FakeNav(bus, seed_places()).serve()
    node = await start(bus)
    try:
        battery(bus, 0.07)  # below the watchdog's critical 10 %
        await settle()
        reply = await ask(bus, "take me to the cafe")
        assert reply.startswith("My battery is nearly empty, at 7 percent, so I can't take you there.")
        assert "docking station" in reply
        assert "nearly empty" in await ask(bus, "show me around")
        assert "nearly empty" in await ask(bus, "what are you doing")
        assert nav.goals == []
        assert nav.tours == []
        assert "follow me" in (await ask(bus, "go to the docking station")).lower()
        await until(lambda: nav.goals == [DOCK])
    finally:
        await stop(node)


async def test_low_battery_refuses_a_tour_but_not_one_place() -> None:
    bus = Bus()
    nav = FakeNav(bus, seed_places()).serve()
    node = await start(bus, {**OFFLINE, "battery": {"warn_fraction": 0.3, "critical_fraction": 0.05}})
    try:
        battery(bus, 0.2)
        await settle()
        assert "too low for a whole tour" in await ask(bus, "give me a tour of the labs")
        assert nav.tours == []
        assert "follow me" in (await ask(bus, "take me to the clean room")).lower()
        await until(lambda: nav.goals == ["CLEAN_ROOM"])
    finally:
        await stop(node)


async def test_unknown_battery_is_unknown_not_empty() -> None:
    bus = Bus()
    nav = FakeNav(bus, seed_places()).serve()
    node = await start(bus)
    try:
        battery(bus, float("nan"))
        await settle()
        assert node.robot.readiness().battery is None
        assert "follow me" in (await ask(bus, "take me to the cafe")).lower()
        await until(lambda: nav.goals == ["GUELLY_DELLY"])
        assert "battery unknown" in node.robot.status()
    finally:
        await stop(node)


# ---------------------------------------------------------------- localization, navigation


async def test_lost_for_a_second_refuses_and_says_so() -> None:
    clock = SimClock()
    bus = Bus(clock)
    nav = FakeNav(bus, seed_places()).serve()
    node = await start(bus)
    try:
        bus.publish(topics.LOC_HEALTH, LocalizationHealth(clock.now(), 0.1, True))
        await settle()
        assert "follow me" in (await ask(bus, "take me to the cafe")).lower()  # a blip is not lost
        clock.advance_to(clock.now() + 1.5)
        bus.publish(topics.LOC_HEALTH, LocalizationHealth(clock.now(), 0.1, True))
        await settle()
        reply = await ask(bus, "take me to the clean room")
        assert "lost track of where I am" in reply
        assert "follow me" not in reply.lower()
        await until(lambda: nav.goals == ["GUELLY_DELLY"])
        bus.publish(topics.LOC_HEALTH, LocalizationHealth(clock.now(), 0.9, False))
        await settle()
        assert "follow me" in (await ask(bus, "take me to the clean room")).lower()
    finally:
        await stop(node)


async def test_a_goal_navigation_aborts_at_once_is_not_followed() -> None:
    bus = Bus()
    said: list[str] = []
    bus.subscribe(topics.SAY, Text, lambda m: said.append(m.data))

    async def refuse(goal: NavigateGoal, ctx: GoalContext) -> None:
        raise ActionAborted("I don't know where I am yet")

    bus.actions.serve(topics.NAVIGATE_TO, refuse)
    node = await start(bus)
    try:
        reply = await ask(bus, "take me to the cafe")
        assert reply == "Sorry, I can not take you to the Guelly Delly café: I don't know where I am yet."
        await asyncio.sleep(0.05)
        assert said == []  # announced once, in the reply, not again on /sage/say
        assert not node.robot.nav.navigating
    finally:
        await stop(node)


async def test_a_goal_someone_else_sent_is_what_the_robot_is_doing() -> None:
    bus = Bus()
    node = await start(bus)
    try:
        bus.declare(topics.NAV_STATE, NavigateFeedback, latched=True)
        bus.publish(topics.NAV_STATE, NavigateFeedback(NavState.WAITING_FOR_PEOPLE, "CLEAN_ROOM", 8.0))
        await settle()
        reply = await ask(bus, "why aren't you moving")
        assert reply == "I am waiting for people to make room, on the way to the Clean Room."
        bus.publish(topics.NAV_STATE, NavigateFeedback(NavState.IDLE))
        await settle()
        assert (await ask(bus, "what are you doing?")).startswith("I am standing still, ready to go")
    finally:
        await stop(node)


# ---------------------------------------------------------------- the rules alone


@pytest.mark.parametrize(
    ("ready", "drive", "dock", "tour"),
    [
        (Readiness(), None, None, None),
        (Readiness(estop=True), Refusal.ESTOP, Refusal.ESTOP, Refusal.ESTOP),
        (Readiness(battery=0.05), Refusal.BATTERY, None, Refusal.BATTERY),
        (Readiness(battery=0.2), None, None, Refusal.BATTERY),
        (Readiness(battery=None, lost=True), Refusal.LOST, Refusal.LOST, Refusal.LOST),
        (Readiness(battery=0.05, lost=True), Refusal.BATTERY, Refusal.LOST, Refusal.BATTERY),
        (Readiness(estop=True, battery=0.05, lost=True), Refusal.ESTOP, Refusal.ESTOP, Refusal.ESTOP),
    ],
)  # fmt: skip
def test_readiness_rules(
    ready: Readiness, drive: Refusal | None, dock: Refusal | None, tour: Refusal | None
) -> None:
    def kind(r: tuple[Refusal, str] | None) -> Refusal | None:
        return r[0] if r else None

    assert kind(ready.refuse_drive("CLEAN_ROOM")) is drive
    assert kind(ready.refuse_drive(DOCK)) is dock
    assert kind(ready.refuse_tour()) is tour


def test_battery_percent_is_rounded_down_but_not_by_float_error() -> None:
    assert Readiness(battery=0.29).battery_percent == 29
    assert Readiness(battery=0.096).battery_percent == 9
