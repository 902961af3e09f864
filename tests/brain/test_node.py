"""The brain node on a real Bus: the converse action, events turned into speech, idle reset."""

from __future__ import annotations

import asyncio
import datetime as dt
from typing import Any

import pytest

from sage_robot.brain.node import BrainNode
from sage_robot.brain.scripted import ScriptedServer, Stream, say, text_chunks
from sage_robot.core import topics
from sage_robot.core.actions import ActionResult, GoalStatus
from sage_robot.core.bus import Bus
from sage_robot.core.clock import SimClock
from sage_robot.core.config import Settings
from sage_robot.core.msgs import Event, Text
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


def spoken(bus: Bus) -> list[str]:
    out: list[str] = []
    bus.subscribe(topics.SAY, Text, lambda m: out.append(m.data))
    return out


async def converse(bus: Bus, text: str) -> tuple[list[str], ActionResult]:
    handle = await bus.actions.send_goal(topics.CONVERSE, Text(text))
    feedback = [fb.data async for fb in handle.feedback()]
    return feedback, await asyncio.wait_for(handle.result(), WAIT_S)


async def test_converse_streams_sentences_as_feedback_and_returns_the_reply() -> None:
    bus = Bus()
    node = await start(bus)
    try:
        feedback, result = await asyncio.wait_for(converse(bus, "hello"), WAIT_S)
        assert result.ok
        assert len(feedback) == 2
        assert result.value == Text(" ".join(feedback))
        assert node.stats() == {"brain": "offline", "turns": 1}
        feedback, result = await asyncio.wait_for(converse(bus, "   "), WAIT_S)
        assert feedback == [result.value.data]
        assert "did not catch that" in result.value.data
    finally:
        await stop(node)


async def test_take_me_to_the_cafe_then_arrival_is_welcomed() -> None:
    bus = Bus()
    nav = FakeNav(bus, seed_places()).serve()
    said = spoken(bus)
    node = await start(bus)
    try:
        _feedback, result = await asyncio.wait_for(converse(bus, "take me to the café"), WAIT_S)
        assert "Guelly Delly" in result.value.data
        await until(lambda: nav.goals == ["GUELLY_DELLY"])
        nav.arrive.set()
        await until(lambda: said)
        assert said[0].startswith("Here we are at the Guelly Delly, engineering student café")
    finally:
        await stop(node)


async def test_navigation_failure_is_announced() -> None:
    bus = Bus()
    nav = FakeNav(bus, seed_places(), fail_reason="the corridor is blocked").serve()
    said = spoken(bus)
    node = await start(bus)
    try:
        await asyncio.wait_for(converse(bus, "go to the clean room"), WAIT_S)
        await until(lambda: nav.goals)
        nav.arrive.set()
        await until(lambda: said)
        assert said == ["Sorry, I could not get to the Clean Room. The corridor is blocked."]
    finally:
        await stop(node)


@pytest.mark.parametrize(
    ("kind", "words"),
    [("blocked_by_people", "Excuse me, could I get by?"), ("lost", "help"),
     ("battery_low", "return to my dock"), ("battery_critical", "docking station")],
)  # fmt: skip
async def test_events_become_speech(kind: str, words: str) -> None:
    bus = Bus()
    said = spoken(bus)
    node = await start(bus)
    try:
        bus.publish(topics.EVENTS, Event(0.0, "navigator", kind))
        bus.publish(topics.EVENTS, Event(0.0, "navigator", "collision"))  # not spoken
        await until(lambda: said)
        await asyncio.sleep(0.05)
        assert len(said) == 1
        assert words in said[0]
    finally:
        await stop(node)


async def test_conversation_resets_after_idle_time() -> None:
    clock = SimClock()
    bus = Bus(clock)
    nav = FakeNav(bus, seed_places()).serve()
    node = await start(bus, {**OFFLINE, "llm": {"idle_reset_s": 60.0}})
    try:
        await asyncio.wait_for(converse(bus, "where is the clean room"), WAIT_S)
        clock.advance_to(clock.now() + 61.0)
        _, result = await asyncio.wait_for(converse(bus, "yes"), WAIT_S)
        assert nav.goals == []
        assert "Guelly" not in result.value.data  # the offer was forgotten
        await asyncio.wait_for(converse(bus, "where is the clean room"), WAIT_S)
        clock.advance_to(clock.now() + 30.0)
        await asyncio.wait_for(converse(bus, "yes"), WAIT_S)
        await until(lambda: nav.goals == ["CLEAN_ROOM"])
    finally:
        await stop(node)


async def test_barge_in_cancels_the_converse_goal_with_the_llm() -> None:
    async with ScriptedServer() as server:
        long = "Let me tell you a story. " + "It goes on and on " * 80 + "."
        server.add(Stream(text_chunks(long, 5), delay_s=0.01), say("Sure, what else?"))
        bus = Bus()
        node = await start(bus, {**OFFLINE, "llm": {"base_url": server.base_url, "max_retries": 0}})
        try:
            handle = await bus.actions.send_goal(topics.CONVERSE, Text("tell me a story"))
            first = await asyncio.wait_for(handle.feedback().__anext__(), WAIT_S)
            assert first == Text("Let me tell you a story.")
            result = await asyncio.wait_for(handle.cancel(), WAIT_S)
            assert result.status is GoalStatus.CANCELED
            _, nxt = await asyncio.wait_for(converse(bus, "stop, something else"), WAIT_S)
            assert nxt.value == Text("Sure, what else?")
            assert server.requests[1]["messages"][-2] == {
                "role": "assistant",
                "content": "Let me tell you a story.",
            }
        finally:
            await stop(node)


async def test_llm_arrival_welcome_is_spoken_on_say() -> None:
    async with ScriptedServer([say("Welcome to the clean room! Mind the bunny suits.")]) as server:
        bus = Bus()
        said = spoken(bus)
        node = await start(bus, {**OFFLINE, "llm": {"base_url": server.base_url}})
        node.brain._today = lambda: dt.date(2026, 1, 1)  # type: ignore[attr-defined]
        try:
            bus.publish(topics.EVENTS, Event(0.0, "navigator", "arrived", "", {"place": "CLEAN_ROOM"}))
            await until(lambda: len(said) == 2)
            assert said == ["Welcome to the clean room!", "Mind the bunny suits."]
            assert "arrived at CLEAN_ROOM" in server.requests[0]["messages"][-1]["content"]
        finally:
            await stop(node)
