"""Tool calls assembled across stream chunks, as different servers send them."""

from __future__ import annotations

import json

from hypothesis import given
from hypothesis import strategies as st

from sage_robot.brain.scripted import chunk, text_chunks, tool_call_chunks
from sage_robot.brain.stream import StreamAssembler

ARGS = {"location": "the clean room", "note": 'quote " and {braces}'}


def feed_all(chunks) -> StreamAssembler:
    asm = StreamAssembler()
    for c in chunks:
        asm.feed(c)
    return asm


def test_openai_fragments_two_calls() -> None:
    asm = feed_all(tool_call_chunks([("set_goal", ARGS), ("list_places", {})], "openai", 3))
    calls = asm.finished_calls()
    assert [(c.id, c.name) for c in calls] == [
        ("call_set_goal_0", "set_goal"),
        ("call_list_places_1", "list_places"),
    ]
    assert json.loads(calls[0].arguments) == ARGS
    assert json.loads(calls[1].arguments) == {}


def test_ollama_whole_calls_all_at_index_zero() -> None:
    asm = feed_all(tool_call_chunks([("set_goal", ARGS), ("describe_place", {"name": "x"})], "ollama"))
    calls = asm.finished_calls()
    assert [c.name for c in calls] == ["set_goal", "describe_place"]
    assert json.loads(calls[0].arguments) == ARGS
    assert json.loads(calls[1].arguments) == {"name": "x"}


def test_calls_without_index_or_id() -> None:
    chunks = [
        chunk({"tool_calls": [{"function": {"name": "set_goal", "arguments": '{"loca'}}]}),
        chunk({"tool_calls": [{"function": {"arguments": 'tion": "dock"}'}}]}),
    ]
    calls = feed_all(chunks).finished_calls()
    assert len(calls) == 1
    assert calls[0].id == "call_0"
    assert json.loads(calls[0].arguments) == {"location": "dock"}


def test_text_and_calls_in_one_stream() -> None:
    asm = feed_all(
        text_chunks("Let me look. ") + tool_call_chunks([("list_places", {})]) + [chunk({}, "tool_calls")]
    )
    assert asm.text == "Let me look. "
    assert asm.finish_reason == "tool_calls"
    assert len(asm.calls) == 1


@given(
    st.integers(min_value=1, max_value=40),
    st.dictionaries(st.text(max_size=5), st.text(max_size=20), max_size=4),
)
def test_any_fragment_size_gives_the_same_arguments(size: int, args: dict[str, str]) -> None:
    calls = feed_all(
        tool_call_chunks([("kb_search", args), ("set_goal", ARGS)], "openai", size)
    ).finished_calls()
    assert json.loads(calls[0].arguments) == args
    assert json.loads(calls[1].arguments) == ARGS
