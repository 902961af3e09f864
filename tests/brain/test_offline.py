"""The offline brain: intents on the development phrasing set, and what each intent does."""

from __future__ import annotations

import asyncio
import re

import pytest
import yaml

from sage_robot.brain.answers import Hit, kb_answer
from sage_robot.brain.intents import INTENTS, classify
from sage_robot.brain.offline import OfflineBrain
from sage_robot.brain.phrases import DONT_KNOW
from sage_robot.core.msgs import BatteryState, PowerStatus
from sage_robot.core.paths import package_data
from sage_robot.core.places import Places

from .conftest import WAIT_S, make_tools, seed_places, until


def dev_phrasings() -> list[tuple[str, str, str]]:
    rows = yaml.safe_load(package_data("brain", "phrasings_dev.yaml").read_text())["phrasings"]
    return [(str(r[0]), r[1], r[2] if len(r) > 2 else "") for r in rows]


PLACES = seed_places()


@pytest.mark.parametrize(("text", "intent", "place"), dev_phrasings(), ids=lambda v: str(v)[:40])
def test_dev_phrasing(text: str, intent: str, place: str) -> None:
    got = classify(text, PLACES)
    assert (got.name, got.place_name) == (intent, place)


def test_phrasing_sets_are_well_formed_and_disjoint() -> None:
    held = yaml.safe_load(package_data("brain", "phrasings_heldout.yaml").read_text())["phrasings"]
    dev = dev_phrasings()
    for rows in (dev, held):
        for r in rows:
            assert r[1] in INTENTS, r
            if len(r) > 2 and r[2]:
                assert r[2] in PLACES, r
    assert not {r[0] for r in dev} & {str(r[0]) for r in held}
    covered = {r[1] for r in dev}
    # "suggest" and "clarify" come from the dialogue state and the semantic guess, not the
    # rules alone: the dialogue sets (dialogues_dev.yaml, test_dialogue.py) cover them.
    assert covered == set(INTENTS) - {"suggest", "clarify"}


@pytest.mark.parametrize(
    ("spoken", "expected"),
    [("Guelly Deli", "GUELLY_DELLY"), ("three d printing lab", "3D_PRINTING_LAB"),
     ("the mecha tronics lab", "MECHATRONICS_LAB"), ("clean rum", "CLEAN_ROOM")],
)  # fmt: skip
def test_stt_misspellings_reach_the_place(spoken: str, expected: str) -> None:
    assert classify(f"take me to {spoken}", PLACES).place_name == expected


@pytest.fixture
def brain(bus, settings):
    return OfflineBrain(make_tools(bus, settings, package_data("brain", "places.yaml")), "SAGE Jarvis")


async def test_navigation_sends_one_goal_and_returns_at_once(brain, nav) -> None:
    said: list[str] = []
    result = await asyncio.wait_for(brain.respond("Take me to the Guelly Deli", said.append), WAIT_S)
    await until(lambda: nav.goals)
    assert nav.goals == ["GUELLY_DELLY"]
    assert said == result.sentences
    assert "Guelly Delly" in result.reply
    assert [c.name for c in result.tool_calls] == ["set_goal"]
    assert brain.robot.nav.navigating
    assert brain.robot.nav.target == "GUELLY_DELLY"


async def test_unknown_place_lists_places(brain, nav) -> None:
    result = await brain.respond("take me to the moon")
    assert nav.goals == []
    assert "moon" in result.reply
    assert "Bio Engineering Lab" in result.reply


async def test_where_is_then_yes_goes_there(brain, nav) -> None:
    first = await brain.respond("where is the clean room?")
    assert "Clean Room" in first.reply
    assert first.reply.endswith("?")
    assert nav.goals == []
    await brain.respond("yes please")
    await until(lambda: nav.goals)
    assert nav.goals == ["CLEAN_ROOM"]


async def test_cancel_stops_the_running_goal(brain, nav) -> None:
    await brain.respond("go to the mechatronics lab")
    await until(lambda: nav.goals)
    result = await brain.respond("stop")
    assert nav.cancels == 1
    assert "stopped" in result.reply
    assert not brain.robot.nav.navigating


async def test_where_am_i_names_the_nearest_place(brain, nav) -> None:
    result = await brain.respond("where are we")
    assert result.reply == "We are at the Guelly Delly."


async def test_battery_from_the_last_reading(brain, bus) -> None:
    assert "can not read" in (await brain.respond("how is your battery")).reply
    brain.robot.on_battery(BatteryState(0.0, 15.1, 0.734, PowerStatus.CHARGING))
    assert (
        await brain.respond("what's your battery level")
    ).reply == "My battery is at 73 percent and charging."


async def test_ip_address_is_spoken_with_dots_as_words(brain) -> None:
    result = await brain.respond("what is your i p address")
    assert result.reply.startswith("My address is ")
    assert " dot " in result.reply
    assert not re.search(r"\d\.\d", result.reply)


async def test_tour_by_theme(brain, nav) -> None:
    result = await brain.respond("take me on a tour of the labs")
    await until(lambda: nav.tours)
    stops = nav.tours[0]
    assert 2 <= len(stops) <= 8
    assert "BIO_ENG_LAB" in stops
    assert not {"GUELLY_DELLY", "BATHROOMS", "DOCKING_STATION", "HESSE_CENTER"} & set(stops)
    assert "stops" in result.reply


async def test_questions_answered_from_the_kb_trimmed_and_speakable(brain, real_kb) -> None:
    result = await brain.respond("how do I get something printed in 3D?")
    assert result.reply.startswith("Any student of the university can submit a print")
    assert 1 <= len(result.sentences) <= 3
    assert "http" not in result.reply
    cleanroom = await brain.respond("What do you need to wear in the cleanroom?")
    assert "gown" in cleanroom.reply


async def test_honest_dont_know(brain, real_kb) -> None:
    assert (await brain.respond("what is the capital of mongolia")).reply == DONT_KNOW


async def test_kb_down_is_said_honestly(brain) -> None:
    result = await brain.respond("when was the college founded")
    assert "knowledge base is not running" in result.reply


def test_kb_answer_starts_at_the_best_sentence_and_is_speakable() -> None:
    text = "Intro words. The dean is **Doug Tougaw**. He teaches circuits. He likes bikes. See valpo.edu."
    hit = Hit(text, "People", "Dean", similarity=0.5)
    expected = "The dean is Doug Tougaw. He teaches circuits. He likes bikes."
    assert kb_answer("who is the dean", [hit]) == expected
    assert kb_answer("who is the dean", [Hit("Nothing relevant at all.", similarity=0.1)]) is None


async def test_navigation_absent_is_an_honest_error(brain) -> None:
    result = await brain.respond("take me to the cafe")
    assert "navigation is not running" in result.reply
    assert result.tool_calls[0].result.ok is False


async def test_places_come_from_the_bus_service_before_the_file(brain, nav) -> None:
    nav.places = Places([p for p in seed_places() if p.name in ("CLEAN_ROOM", "BATHROOMS")])
    assert (await brain.robot.places()).names() == ["CLEAN_ROOM", "BATHROOMS"]
    result = await brain.respond("what places can you take me to")
    assert result.reply == "I can take you to the Clean Room and the bathrooms. Where would you like to go?"


async def test_where_am_i_before_any_pose_estimate(brain, nav) -> None:
    nav.position = (float("nan"), float("nan"))
    result = await brain.respond("where am i")
    assert (
        result.reply
        == "I am not sure where we are: the robot does not know where it is yet, no pose estimate."
    )


async def test_describe_place_adds_the_kb_passage_about_it(brain, real_kb) -> None:
    result = await brain.respond("what is the clean room?")
    assert [c.name for c in result.tool_calls] == ["describe_place", "kb_search"]
    assert result.sentences[0] == (
        "Here is what I know about the Clean Room: controlled environment for sensitive fabrication."
    )
    assert "dust" in result.reply  # from the clean room's own KB document
    assert result.sentences[-1] == "Would you like to go there?"
    assert 3 <= len(result.sentences) <= 4
    assert len(set(result.sentences)) == len(result.sentences)
    followed = await brain.respond("yes")
    assert followed.intent == "navigate"


async def test_describe_place_without_kb_does_not_repeat_the_description(brain) -> None:
    result = await brain.respond("what is the clean room?")
    assert result.reply == (
        "Here is what I know about the Clean Room: controlled environment for sensitive "
        "fabrication. Would you like to go there?"
    )  # the talking point "This is the clean room, a controlled environment ..." says it again


async def test_spoken_errors_say_right_now_once(brain) -> None:
    result = await brain.respond("take me to the 3d printing lab")
    expected = "Sorry, I can not take you to the 3D Printing Lab: navigation is not running right now."
    assert result.reply == expected
    assert (await brain.respond("when does the cafe open")).reply.count("right now") == 1


def test_a_statement_then_a_question_is_a_question() -> None:
    got = classify("I need help with calculus homework, where can I go?", PLACES)
    assert got.name == "question"
    assert classify("I am hungry, where can I get breakfast?", PLACES).place_name == "GUELLY_DELLY"
