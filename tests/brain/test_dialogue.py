"""Dialogue state, consent, natural names and the semantic fallback of the offline brain.

The brain is the real offline brain on a real bus with the small navigation node of
``conftest.py``; the semantic tests use the real all-MiniLM-L6-v2 from its installed
package (through the same lazy loader `sage chat` uses).
"""

from __future__ import annotations

import asyncio
import json
import subprocess
import sys

import pytest

from sage_robot.bench.brain_dialogues import load_dialogues, score_dialogues
from sage_robot.brain.dialogue import DIALOGUE_IDLE_S, MAX_SESSIONS, Dialogues, pick, resolve
from sage_robot.brain.intents import Intent, classify, prepare, strip_wake
from sage_robot.brain.offline import OfflineBrain
from sage_robot.brain.phrases import be, place_phrase
from sage_robot.brain.semantic import SemanticMatcher, cached_source
from sage_robot.cli.chat import LazyEmbedder
from sage_robot.core.bus import Bus
from sage_robot.core.clock import SimClock
from sage_robot.core.config import Settings
from sage_robot.core.paths import package_data

from .conftest import WAIT_S, FakeNav, make_tools, seed_places, until

PLACES = seed_places()
EMBEDDER = cached_source(LazyEmbedder)  # one model for the whole module, loaded on first use
CHAT_TIMEOUT_S = 120.0


def brain_on(bus: Bus, settings, semantic: bool = False) -> OfflineBrain:
    tools = make_tools(bus, settings, package_data("brain", "places.yaml"))
    return OfflineBrain(tools, "SAGE Jarvis", bus.clock, EMBEDDER if semantic else None)


@pytest.fixture
def brain(bus, settings):
    return brain_on(bus, settings)


async def say(brain: OfflineBrain, text: str, session: str = "robot") -> str:
    return (await asyncio.wait_for(brain.respond(text, session=session), WAIT_S * 6)).reply


# ---------------------------------------------------------------- the visitors


async def test_lunch_then_take_me_there_goes_to_the_cafe(brain, nav) -> None:
    reply = await say(brain, "I'm starving, where can I grab some lunch around here? Take me there.")
    await until(lambda: nav.goals)
    assert nav.goals == ["GUELLY_DELLY"]
    assert reply == "Sure, follow me to the Guelly Delly café!"


async def test_consent_given_is_not_asked_again(brain, nav) -> None:
    reply = await say(brain, "where's the nearest bathroom, can you take me")
    await until(lambda: nav.goals)
    assert nav.goals == ["BATHROOMS"]
    assert "?" not in reply
    assert reply == "Sure, follow me to the bathrooms!"


async def test_plural_names_read_naturally(brain, nav) -> None:
    reply = await say(brain, "where are the restrooms")
    assert reply.startswith("The bathrooms are on my map")
    assert nav.goals == []


def test_place_phrases() -> None:
    names = {p.name: place_phrase(p) for p in PLACES}
    assert names["GUELLY_DELLY"] == "the Guelly Delly café"
    assert names["BATHROOMS"] == "the bathrooms"
    assert names["CLEAN_ROOM"] == "the Clean Room"
    assert names["ECE_LAB_1"] == "the E C E Lab 1"
    assert names["DOCKING_STATION"] == "the docking station"
    assert [be(p) for p in (PLACES.get("BATHROOMS"), PLACES.get("VALPO_ROBOTICS"))] == ["are", "is"]


# ---------------------------------------------------------------- follow-ups


async def test_take_me_there_what_is_there_and_how_far(brain, nav) -> None:
    assert (await say(brain, "where is the heat power lab")).endswith("Shall I take you there?")
    described = await brain.respond("what's there?")
    assert [c.name for c in described.tool_calls][:1] == ["describe_place"]
    assert described.tool_calls[0].arguments == {"name": "HEAT_POWER_LAB"}
    far = await brain.respond("how far is it?")
    assert [c.name for c in far.tool_calls] == ["where_am_i"]
    assert "meters from here" in far.reply  # the fake robot stands near the café
    assert nav.goals == []
    await say(brain, "ok, take me there")
    await until(lambda: nav.goals)
    assert nav.goals == ["HEAT_POWER_LAB"]


async def test_which_one_then_the_second_one(brain, nav) -> None:
    asked = await say(brain, "take me to the ece lab")
    assert asked == "Which one do you mean: the E C E Lab 1 or the E C E Lab 2?"
    assert nav.goals == []
    await say(brain, "the second one")
    await until(lambda: nav.goals)
    assert nav.goals == ["ECE_LAB_2"]


async def test_a_kind_of_place_asks_which_never_says_unknown_place(brain, nav) -> None:
    asked = await say(brain, "take me to the labs")
    assert asked.startswith("There are 10 of those: the Bio Engineering Lab, the Manufacturing Lab")
    assert "do not know" not in asked
    await say(brain, "the second one")
    await until(lambda: nav.goals)
    assert nav.goals == ["MANUFACTURING_LAB"]


async def test_a_pick_from_the_list_of_places(brain, nav) -> None:
    await say(brain, "which places can we visit?")
    await say(brain, "take me to the third one")
    await until(lambda: nav.goals)
    assert nav.goals == [PLACES.names()[2]]


async def test_take_me_there_with_nothing_said_asks_where(brain, nav) -> None:
    assert (await say(brain, "take me there")).startswith("Where would you like to go?")
    assert (await say(brain, "yes")).startswith("Sorry, I did not catch that")
    assert nav.goals == []


async def test_no_drops_the_offer(brain, nav) -> None:
    await say(brain, "where is the clean room")
    assert (await say(brain, "no thanks")).startswith("No problem")
    await say(brain, "yes")
    assert nav.goals == []


async def test_sessions_keep_their_own_state(brain, nav) -> None:
    await say(brain, "where is the clean room", session="web-1")
    await say(brain, "yes", session="chat")  # another conversation: no offer there
    assert nav.goals == []
    await say(brain, "yes", session="web-1")
    await until(lambda: nav.goals)
    assert nav.goals == ["CLEAN_ROOM"]


async def test_state_expires_after_idle_time_on_the_clock(settings) -> None:
    clock = SimClock()
    bus = Bus(clock)
    nav = FakeNav(bus, PLACES).serve()
    brain = brain_on(bus, settings)
    await say(brain, "where is the clean room")
    clock.advance_to(clock.now() + DIALOGUE_IDLE_S + 1.0)
    await say(brain, "yes")
    assert nav.goals == []


def test_the_store_is_bounded_and_expires() -> None:
    store = Dialogues()
    for i in range(MAX_SESSIONS + 5):
        store.get(f"s{i}", now=float(i))
    assert len(store) == MAX_SESSIONS
    assert "s0" not in store  # the one idle longest went first
    store.get("late", now=MAX_SESSIONS + 5 + DIALOGUE_IDLE_S + 1.0)
    assert len(store) == 1


def test_resolve_pronouns_and_picks() -> None:
    store = Dialogues()
    state = store.get("x", 0.0)
    cafe, lab1, lab2 = PLACES.get("GUELLY_DELLY"), PLACES.get("ECE_LAB_1"), PLACES.get("ECE_LAB_2")
    state.place = cafe

    def intent_of(text: str) -> Intent:
        t = strip_wake(prepare(text))
        return resolve(t, classify(text, PLACES), state, PLACES)

    there = intent_of("what's there?")
    assert (there.name, there.place_name) == ("describe_place", cafe.name)
    assert intent_of("and where is it").place_name == cafe.name
    assert intent_of("how far is it").name == "distance"
    assert intent_of("take me there").place_name == cafe.name
    assert intent_of("take me to the clean room").place_name == "CLEAN_ROOM"  # a named place wins
    state.choices, state.choice_intent = (lab1, lab2), "where_is"
    assert pick("number two", state.choices) == lab2
    assert pick("the last one", state.choices) == lab2
    assert pick("the fifth one", state.choices) is None
    first = intent_of("the first one")
    assert (first.name, first.place_name) == ("where_is", lab1.name)


# ---------------------------------------------------------------- semantic fallback


async def test_semantic_guess_is_offered_never_driven_unasked(bus, settings, nav) -> None:
    brain = brain_on(bus, settings, semantic=True)
    reply = await say(brain, "I'd like to wash my hands")
    assert reply.startswith("Do you mean the bathrooms")
    assert nav.goals == []
    await say(brain, "yes please")
    await until(lambda: nav.goals)
    assert nav.goals == ["BATHROOMS"]


@pytest.mark.parametrize(
    "text", ["take me to the moon", "take me to their office", "blah blah", "what is the capital of France"]
)
async def test_off_topic_and_unclear_input_never_drives(bus, settings, nav, text) -> None:
    brain = brain_on(bus, settings, semantic=True)
    await say(brain, text)
    await say(brain, "yes")
    assert nav.goals == []


async def test_without_an_embedder_the_guess_is_empty(bus) -> None:
    guess = await SemanticMatcher(lambda: None).guess("I'd like to wash my hands", PLACES, bus.clock)
    assert guess.place is None
    assert not guess.offered


async def test_development_dialogues_score(kb_service) -> None:
    """The development dialogues with the real KB and embedder (the held-out ones are
    only read by `sage bench brain`)."""
    dialogues = load_dialogues(package_data("brain", "dialogues_dev.yaml"))
    score = await score_dialogues(dialogues, EMBEDDER, kb_service)
    assert score.turns >= 60
    assert score.wrong_navigations == 0, score.misses
    assert score.right / score.turns >= 0.95, score.misses


def test_dialogue_sets_are_well_formed_and_disjoint() -> None:
    dev = load_dialogues(package_data("brain", "dialogues_dev.yaml"))
    held = load_dialogues(package_data("brain", "dialogues_heldout.yaml"))
    assert len(dev) + len(held) >= 40
    assert not {d.name for d in dev} & {d.name for d in held}
    for d in (*dev, *held):
        for _, expected in d.turns:
            for e in expected:
                tool, _, place = e.partition(" ")
                assert tool in {"none", "set_goal", "describe_place", "where_am_i", "kb_search",
                                "cancel_goal", "list_places", "battery_status"}, (d.name, e)  # fmt: skip
                assert not place or place in PLACES, (d.name, e)


# ---------------------------------------------------------------- sage chat --json


def test_chat_json_is_one_conversation_one_line_per_turn() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "sage_robot.cli.main", "--log-level", "WARNING", "chat", "--json"],
        input="where is the clean room\n\nhow far is it\nyes\n",
        capture_output=True,
        text=True,
        timeout=CHAT_TIMEOUT_S,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    replies = [json.loads(line) for line in proc.stdout.splitlines()]
    assert [r["intent"] for r in replies] == ["where_is", "distance", "navigate"]
    assert set(replies[0]) == {"reply", "sentences", "tool_calls", "brain", "fell_back", "error", "intent"}
    assert replies[2]["tool_calls"][0]["arguments"] == {"location": "CLEAN_ROOM"}


# ---------------------------------------------------------------- the node


async def test_node_keeps_a_state_per_session_and_uses_the_shared_embedder(bus) -> None:
    from sage_robot.brain.base import Utterance
    from sage_robot.brain.node import BrainNode
    from sage_robot.core import topics
    from sage_robot.core.embedding import SENTENCE_EMBEDDER
    from sage_robot.core.node import NodeContext

    nav = FakeNav(bus, PLACES).serve()
    ctx = NodeContext(bus, bus.clock, Settings.model_validate(
        {"nav": {"waypoints": str(package_data("brain", "places.yaml"))}}))  # fmt: skip
    ctx.resources[SENTENCE_EMBEDDER] = LazyEmbedder()
    node = BrainNode(ctx)
    await node.setup()

    async def converse(goal: object) -> str:
        handle = await bus.actions.send_goal(topics.CONVERSE, goal)
        result = await asyncio.wait_for(handle.result(), WAIT_S * 6)
        return str(result.value.data)

    try:
        assert (await converse(Utterance("I'd like to wash my hands", "web-7"))).startswith("Do you mean")
        await converse(Utterance("yes", "robot"))  # the robot's own conversation has no offer
        assert nav.goals == []
        await converse(Utterance("yes", "web-7"))
        await until(lambda: nav.goals)
        assert nav.goals == ["BATHROOMS"]
    finally:
        await node.teardown()
        await node._close()


# ---------------------------------------------------------------- the LLM brain


async def test_llm_history_and_rules_are_per_session(bus, settings) -> None:
    from sage_robot.brain.llm import LlmBrain
    from sage_robot.brain.scripted import ScriptedServer
    from sage_robot.brain.scripted import say as model_says

    async with ScriptedServer() as server:
        llm = Settings.model_validate({"llm": {"base_url": server.base_url, "max_retries": 0}})
        brain = LlmBrain(llm, make_tools(bus, llm, package_data("brain", "places.yaml")), bus.clock)
        server.add(model_says("It is down the hall."), model_says("Hello!"), model_says("Follow me!"))
        await brain.respond("where is the clean room", session="a")
        await brain.respond("hi", session="b")
        await brain.respond("take me there", session="a")
    user_turns = [[m["content"] for m in r["messages"] if m["role"] == "user"] for r in server.requests]
    assert user_turns == [["where is the clean room"], ["hi"], ["where is the clean room", "take me there"]]
    system = server.requests[0]["messages"][0]["content"]
    assert "do not ask for consent again" in system
    assert '"the second one"' in system
