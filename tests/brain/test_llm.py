"""The LLM agent against a real HTTP server on loopback speaking the OpenAI streaming protocol.

The real ``openai`` client talks to :class:`ScriptedServer` (aiohttp) over a socket;
nothing of the client is mocked. Each test scripts the model's replies.
"""

from __future__ import annotations

import asyncio
import datetime as dt
import json
from typing import Any

import pytest

from sage_robot.brain.llm import ENDPOINT_DOWN, LOST_CONNECTION, LlmBrain
from sage_robot.brain.scripted import ScriptedServer, Status, Stream, call, say, text_chunks
from sage_robot.core.config import Settings
from sage_robot.core.paths import package_data

from .conftest import WAIT_S, make_tools, until

pytestmark = pytest.mark.filterwarnings("ignore::ResourceWarning")


@pytest.fixture
async def server():
    async with ScriptedServer() as s:
        yield s


def llm_settings(base_url: str, **llm) -> Settings:
    return Settings.model_validate({"llm": {"base_url": base_url, "timeout_s": 5.0, "max_retries": 2, **llm}})


def make_brain(bus, server, **llm) -> LlmBrain:
    settings = llm_settings(server.base_url, **llm)
    tools = make_tools(bus, settings, package_data("brain", "places.yaml"))
    return LlmBrain(settings, tools, bus.clock, today=lambda: dt.date(2026, 4, 3))


async def respond(brain: LlmBrain, text: str, said: list[str] | None = None):
    return await asyncio.wait_for(brain.respond(text, (said if said is not None else []).append), WAIT_S)


def tool_messages(request: dict[str, Any]) -> list[dict[str, Any]]:
    return [m for m in request["messages"] if m["role"] == "tool"]


async def test_sentences_are_handed_on_while_the_model_still_streams(bus, server) -> None:
    text = "Hello there, I am SAGE. The café is just down the hall. Shall we go?"
    server.add(Stream(text_chunks(text, 4), delay_s=0.01))
    brain = make_brain(bus, server)
    seen: list[tuple[str, int]] = []
    result = await asyncio.wait_for(
        brain.respond("hi", lambda s: seen.append((s, server.chunks_sent))), WAIT_S
    )
    assert [s for s, _ in seen] == [
        "Hello there, I am SAGE.",
        "The café is just down the hall.",
        "Shall we go?",
    ]
    assert seen[0][1] < server.chunks_sent - 5  # the first sentence left long before the end
    assert result.reply == " ".join(s for s, _ in seen)
    assert result.brain == "llm"


async def test_fragmented_tool_arguments_set_the_goal(bus, server, nav) -> None:
    server.add(call(("set_goal", {"location": "the cafe"})), say("Follow me to the Guelly Delly!"))
    brain = make_brain(bus, server)
    result = await respond(brain, "take me to the café")
    await until(lambda: nav.goals)
    assert nav.goals == ["GUELLY_DELLY"]
    assert [c.name for c in result.tool_calls] == ["set_goal"]
    assert result.tool_calls[0].result.ok
    assert result.tool_calls[0].arguments == {"location": "the cafe"}
    fed = tool_messages(server.requests[1])
    assert fed[0]["tool_call_id"] == "call_set_goal_0"
    assert json.loads(fed[0]["content"])["place"] == "GUELLY_DELLY"
    assert result.reply == "Follow me to the Guelly Delly!"


@pytest.mark.parametrize("style", ["openai", "ollama"])
async def test_two_calls_in_one_turn(bus, server, nav, style) -> None:
    server.add(
        call(("describe_place", {"name": "clean room"}), ("set_goal", {"location": "CLEAN_ROOM"}),
             style=style, text="Let me check. "),
        say("The clean room is for sensitive fabrication. Off we go!"),
    )  # fmt: skip
    brain = make_brain(bus, server)
    said: list[str] = []
    result = await respond(brain, "what is the clean room? take me there", said)
    await until(lambda: nav.goals)
    assert [c.name for c in result.tool_calls] == ["describe_place", "set_goal"]
    assert all(c.result.ok for c in result.tool_calls)
    assert nav.goals == ["CLEAN_ROOM"]
    assistant = [m for m in server.requests[1]["messages"] if m["role"] == "assistant"][-1]
    ids = [tc["id"] for tc in assistant["tool_calls"]]
    assert [m["tool_call_id"] for m in tool_messages(server.requests[1])] == ids
    assert len(set(ids)) == 2
    assert said[0] == "Let me check."


async def test_429_is_retried_then_succeeds(bus, server) -> None:
    server.add(Status(429, "slow down"), say("Hello!"))
    result = await respond(make_brain(bus, server), "hi")
    assert result.reply == "Hello!"
    assert not result.fell_back
    assert len(server.requests) == 2


async def test_500_falls_back_to_the_offline_brain_and_stays_offline_a_while(bus, server, nav) -> None:
    server.add(Status(500), Status(500), Status(500))
    brain = make_brain(bus, server, max_retries=2, offline_retry_s=60.0)
    said: list[str] = []
    result = await respond(brain, "take me to the clean room", said)
    assert len(server.requests) == 3  # first try and two retries
    assert said[0] == ENDPOINT_DOWN
    assert result.fell_back
    assert "InternalServerError" in result.error
    await until(lambda: nav.goals)
    assert nav.goals == ["CLEAN_ROOM"]
    again = await respond(brain, "what is your battery level")
    assert len(server.requests) == 3
    assert again.fell_back
    assert ENDPOINT_DOWN not in again.reply


async def test_endpoint_not_listening_falls_back(bus, server) -> None:
    url = server.base_url
    await server.close()
    brain = make_brain(bus, server, max_retries=0)
    brain.client = brain.client.with_options(base_url=url)
    result = await respond(brain, "hello")
    assert result.fell_back
    assert result.sentences[0] == ENDPOINT_DOWN
    assert "Hello" in result.reply


async def test_malformed_arguments_go_back_as_a_tool_error(bus, server, nav) -> None:
    server.add(
        call(("set_goal", '{"location": "clean ro')),
        call(("set_goal", {"location": "clean room"})),
        say("On our way."),
    )
    result = await respond(make_brain(bus, server), "clean room please")
    await until(lambda: nav.goals)
    first_error = json.loads(tool_messages(server.requests[1])[0]["content"])["error"]
    assert "not valid JSON" in first_error
    assert [c.result.ok for c in result.tool_calls] == [False, True]
    assert nav.goals == ["CLEAN_ROOM"]


async def test_schema_violations_and_unknown_places_are_tool_errors(bus, server, nav) -> None:
    server.add(
        call(("set_goal", {"place": "cafe"}), ("set_goal", {"location": "the moon"}),
             ("fly_away", {}), ("kb_search", {"query": "x", "top_k": 99})),
        say("Sorry, I can not do that."),
    )  # fmt: skip
    result = await respond(make_brain(bus, server), "fly me to the moon")
    errors = [json.loads(m["content"])["error"] for m in tool_messages(server.requests[1])]
    assert errors[0] == ("invalid arguments for set_goal: location: required, missing; "
                         "place: unexpected argument (the arguments are: location)")
    assert "the moon" in errors[1]
    assert "GUELLY_DELLY" in errors[1]
    assert "no tool named 'fly_away'" in errors[2]
    assert "top_k" in errors[3]
    assert nav.goals == []
    assert result.reply == "Sorry, I can not do that."


async def test_dropped_connection_before_any_word_falls_back(bus, server) -> None:
    server.add(Stream(text_chunks("Hello there friend."), drop_after=1))
    result = await respond(make_brain(bus, server, max_retries=0), "hello")
    assert result.fell_back
    assert result.sentences[0] == ENDPOINT_DOWN


async def test_dropped_connection_mid_reply_keeps_what_was_said(bus, server) -> None:
    text = "The college was founded long ago. It has many labs and"
    server.add(Stream(text_chunks(text, 8), drop_after=8))
    brain = make_brain(bus, server, max_retries=0)
    result = await respond(brain, "tell me about the college")
    assert result.sentences == ["The college was founded long ago.", LOST_CONNECTION]
    assert not result.fell_back
    assert brain.history[-1][-1]["content"].startswith("The college")


async def test_tool_rounds_are_bounded(bus, server) -> None:
    server.add(*[call(("list_places", {})) for _ in range(3)], say("Here is what I found."))
    brain = make_brain(bus, server, max_tool_rounds=3)
    result = await respond(brain, "loop forever")
    assert len(server.requests) == 4
    assert "tools" not in server.requests[3]
    assert all("tools" in r for r in server.requests[:3])
    assert len(result.tool_calls) == 3
    assert result.reply == "Here is what I found."


async def test_system_prompt_is_rebuilt_each_turn(bus, server, nav) -> None:
    server.add(say("Okay."), call(("set_goal", {"location": "dock"})), say("Going home."), say("Sure."))
    brain = make_brain(bus, server)
    await respond(brain, "hi")
    await respond(brain, "go to your dock")
    await respond(brain, "how far is it")
    first, last = server.requests[0]["messages"][0], server.requests[-1]["messages"][0]
    assert first["role"] == "system"
    assert "SAGE Jarvis" in first["content"]
    assert "Friday, April 3, 2026" in first["content"]
    assert "CLEAN_ROOM: Controlled environment for sensitive fabrication" in first["content"]
    assert "Navigation status: idle" in first["content"]
    assert "navigating to DOCKING_STATION" in last["content"]
    assert [m["content"] for m in server.requests[-1]["messages"] if m["role"] == "user"] == [
        "hi", "go to your dock", "how far is it"]  # fmt: skip


async def test_history_keeps_twelve_turns_and_resets(bus, server) -> None:
    server.add(*[say(f"Reply {i}.") for i in range(14)])
    brain = make_brain(bus, server)
    for i in range(14):
        await respond(brain, f"turn {i}")
    users = [m["content"] for m in server.requests[-1]["messages"] if m["role"] == "user"]
    assert users == [f"turn {i}" for i in range(1, 14)]  # 12 remembered + the new one
    brain.reset()
    assert brain.history == []


async def test_barge_in_cancels_generation(bus, server) -> None:
    server.add(Stream(text_chunks("First sentence here. " + "and more words " * 60, 5), delay_s=0.01))
    brain = make_brain(bus, server)
    said: list[str] = []
    task = asyncio.ensure_future(brain.respond("tell me everything", said.append))
    await until(lambda: said)
    sent_at_cancel = server.chunks_sent
    task.cancel()
    with pytest.raises(asyncio.CancelledError):
        await asyncio.wait_for(task, WAIT_S)
    await asyncio.sleep(0.1)
    assert server.chunks_sent <= sent_at_cancel + 3  # the server stopped being read from
    assert brain.history[-1][-1]["content"] == "First sentence here."


async def test_arrival_event_turn_uses_the_model_and_enters_history(bus, server) -> None:
    server.add(say("Welcome to the Guelly Delly, home of the best bagels!"))
    brain = make_brain(bus, server)
    result = await asyncio.wait_for(
        brain.react("You have just arrived at GUELLY_DELLY.", "Here we are."), WAIT_S
    )
    assert result.reply.startswith("Welcome to the Guelly Delly")
    assert server.requests[0]["messages"][-1]["content"].startswith("[event] You have just arrived")


async def test_arrival_event_without_endpoint_uses_the_fallback_line(bus, server) -> None:
    server.add(Status(503), Status(503), Status(503))
    brain = make_brain(bus, server)
    result = await asyncio.wait_for(brain.react("You have arrived.", "Here we are at the cafe."), WAIT_S)
    assert result.sentences == ["Here we are at the cafe."]
    assert result.fell_back


async def test_slow_endpoint_times_out_and_falls_back(bus, server) -> None:
    server.add(Stream(text_chunks("Too slow."), delay_s=1.0))
    brain = make_brain(bus, server, timeout_s=0.3, max_retries=0)
    result = await respond(brain, "hello")
    assert result.fell_back
    assert "Timeout" in result.error
    assert result.sentences[0] == ENDPOINT_DOWN


async def test_api_key_from_the_key_file_or_a_placeholder(bus, server, tmp_path, monkeypatch) -> None:
    monkeypatch.delenv("SAGE_TEST_LLM_KEY", raising=False)
    keys = tmp_path / "keys.env"
    keys.write_text("SAGE_TEST_LLM_KEY=sk-from-file\n")
    keys.chmod(0o600)
    server.add(say("One."), say("Two."), say("Three."))
    await respond(make_brain(bus, server, api_key_env="SAGE_TEST_LLM_KEY"), "hi")
    settings = Settings.model_validate(
        {"llm": {"base_url": server.base_url, "api_key_env": "SAGE_TEST_LLM_KEY"}, "secrets_file": str(keys)}
    )
    with_file = LlmBrain(settings, make_tools(bus, settings), bus.clock)
    await respond(with_file, "hi")
    monkeypatch.setenv("SAGE_TEST_LLM_KEY", "sk-from-env")
    await respond(LlmBrain(settings, make_tools(bus, settings), bus.clock), "hi")
    assert server.auth == ["Bearer not-needed", "Bearer sk-from-file", "Bearer sk-from-env"]
