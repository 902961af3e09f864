"""The tool registry: schemas, errors as values, and each tool over the bus or loopback HTTP."""

from __future__ import annotations

import os
import socket

import pytest

from sage_robot.brain.scripted import ScriptedServer
from sage_robot.brain.tools import TOOLS, NoArgs, ToolArgs, ToolRegistry, openai_parameters, tool
from sage_robot.core.config import Settings
from sage_robot.core.msgs import BatteryState
from sage_robot.core.paths import package_data

from .conftest import make_tools, until

EXPECTED = {"set_goal", "cancel_goal", "kb_search", "web_search", "get_ip_address", "where_am_i",
            "battery_status", "list_places", "start_tour", "describe_place",
            "plan_tour", "tour_control"}  # fmt: skip


@pytest.fixture
def tools(bus, settings) -> ToolRegistry:
    return make_tools(bus, settings, package_data("brain", "places.yaml"))


def test_every_tool_has_a_valid_openai_spec(tools) -> None:
    assert set(tools.tools) == EXPECTED
    for spec in tools.specs():
        fn = spec["function"]
        assert spec["type"] == "function"
        assert fn["description"]
        assert fn["parameters"]["type"] == "object"


def test_unknown_tool_names_in_a_registry_are_refused(tools) -> None:
    with pytest.raises(ValueError, match="unknown tool"):
        ToolRegistry(tools.ctx, ["set_goal", "teleport"])
    register_again = tool("set_goal", "again", NoArgs)
    with pytest.raises(ValueError, match="registered twice"):
        register_again(TOOLS["set_goal"].fn)


async def test_bad_arguments_are_errors_not_exceptions(tools) -> None:
    cases = [
        ("set_goal", "not json", "not valid JSON"),
        ("set_goal", "[1, 2]", "must be a JSON object"),
        ("set_goal", {"location": 3}, "for set_goal: location: Input should be a valid string (got 3)"),
        ("set_goal", {"location": "x", "speed": 9}, "speed: unexpected argument"),
        ("set_goal", {}, "invalid arguments for set_goal: location: required, missing"),
        ("kb_search", {"query": ""}, "query: String should have at least 1 character (got '')"),
        ("kb_search", {"query": "x", "top_k": 11}, "top_k: Input should be less than or equal to 10"),
        ("start_tour", {"places": "lab"}, "places: Input should be a valid list (got 'lab')"),
        ("cancel_goal", {"now": True}, "now: unexpected argument (the arguments are: none)"),
        ("teleport", {}, "no tool named"),
    ]
    for name, args, words in cases:
        call = await tools.call(name, args)
        assert not call.result.ok, (name, call.result.error)
        assert words in call.result.error, (name, call.result.error)


def test_the_schema_the_llm_is_given_is_generated_from_the_arguments_model(tools) -> None:
    from jsonschema import Draft202012Validator

    for spec in tools.specs():
        fn = spec["function"]
        t = TOOLS[fn["name"]]
        assert issubclass(t.args, ToolArgs)
        assert fn["parameters"] == openai_parameters(t.args) == t.parameters
        Draft202012Validator.check_schema(fn["parameters"])
        assert fn["parameters"]["additionalProperties"] is False
    # The OpenAI function-calling shape, as the hand-written schemas were: no titles, an
    # optional argument as its plain type, limits and defaults kept.
    assert TOOLS["set_goal"].parameters == {
        "type": "object",
        "properties": {"location": {"type": "string", "minLength": 1, "description": "Place name"}},
        "required": ["location"],
        "additionalProperties": False,
    }
    assert TOOLS["start_tour"].parameters == {
        "type": "object",
        "properties": {
            "places": {"type": "array", "items": {"type": "string", "minLength": 1}, "maxItems": 12},
            "theme": {"type": "string"},
        },
        "additionalProperties": False,
    }
    assert TOOLS["kb_search"].parameters["properties"]["top_k"] == {
        "type": "integer", "minimum": 1, "maximum": 10, "default": 3,
    }
    no_args = {"type": "object", "properties": {}, "additionalProperties": False}
    assert TOOLS["list_places"].parameters == no_args


@pytest.mark.parametrize(
    ("name", "args"),
    [
        ("set_goal", {"location": "lab"}),
        ("set_goal", {"location": ""}),
        ("set_goal", {"location": None}),
        ("set_goal", {"place": "lab"}),
        ("kb_search", {"query": "dean", "top_k": 10}),
        ("kb_search", {"query": "dean", "top_k": 0}),
        ("web_search", {"query": "weather", "max_results": 9}),
        ("start_tour", {}),
        ("start_tour", {"places": ["lab"] * 12, "theme": "labs"}),
        ("start_tour", {"places": ["lab"] * 13}),
        ("start_tour", {"places": [""]}),
        ("describe_place", {"name": "hesse", "detail": 1}),
        ("where_am_i", {}),
        ("where_am_i", {"x": 1}),
    ],
)
def test_the_schema_and_the_model_accept_the_same_arguments(name, args) -> None:
    from jsonschema import Draft202012Validator

    t = TOOLS[name]
    by_schema = Draft202012Validator(t.parameters).is_valid(args)
    by_model = isinstance(t.validate(args), ToolArgs)
    assert by_schema == by_model, (name, args, t.validate(args))


async def test_bad_arguments_reach_the_llm_as_a_readable_error(tools, nav) -> None:
    """What the model reads back: one JSON error naming each problem, no traceback, and
    the tool did not run."""
    import json

    call = await tools.call("set_goal", '{"location": "", "speed": "fast"}')
    said = json.loads(call.result.to_json())
    assert said == {"error": "invalid arguments for set_goal: location: String should have at least 1 "
                             "character (got ''); speed: unexpected argument (the arguments are: location)"}
    assert "Traceback" not in call.result.error
    assert call.as_dict()["arguments"] == {"location": "", "speed": "fast"}
    assert nav.goals == []


def test_generated_schemas_inline_references_and_refuse_non_objects() -> None:
    import enum

    from pydantic import BaseModel, Field

    class Speed(str, enum.Enum):
        SLOW = "slow"
        FAST = "fast"

    class DriveArgs(ToolArgs):
        """Docstrings stay in the code."""

        speed: Speed = Field(Speed.SLOW, description="How fast")
        note: str | None = None

    assert openai_parameters(DriveArgs) == {
        "type": "object",
        "properties": {
            "speed": {"type": "string", "enum": ["slow", "fast"], "default": "slow",
                      "description": "How fast"},
            "note": {"type": "string"},
        },
        "additionalProperties": False,
    }

    class Loose(BaseModel):
        x: int = 0

    with pytest.raises(TypeError, match="must be a ToolArgs model"):
        openai_parameters(Loose)  # type: ignore[arg-type]


def test_a_tool_takes_its_arguments_validated(tools) -> None:
    from sage_robot.brain.toolbox import KbSearchArgs, StartTourArgs

    assert TOOLS["kb_search"].validate({"query": "dean"}) == KbSearchArgs(query="dean", top_k=3)
    assert TOOLS["start_tour"].validate({}) == StartTourArgs(places=None, theme=None)


async def test_set_goal_unknown_place_lists_the_places(tools, nav) -> None:
    call = await tools.call("set_goal", '{"location": "the moon"}')
    assert not call.result.ok
    assert "CLEAN_ROOM" in call.result.error
    assert len(call.result.data["places"]) == 16
    assert nav.goals == []


async def test_set_goal_is_non_blocking_and_cancel_goal_stops_it(tools, nav) -> None:
    call = await tools.call("set_goal", {"location": "Guelly Deli"})
    assert call.result.data["status"] == "navigating"
    assert call.result.data["place"] == "GUELLY_DELLY"
    assert call.result.data["description"].startswith("Engineering student café")
    await until(lambda: nav.goals)
    stop = await tools.call("cancel_goal", {})
    assert stop.result.data == {"stopped": True, "was_going_to": "GUELLY_DELLY"}
    assert nav.cancels == 1


async def test_where_am_i_battery_and_places(tools, nav) -> None:
    where = await tools.call("where_am_i", {})
    assert where.result.data["nearest_place"] == "GUELLY_DELLY"
    assert where.result.data["localized"]
    assert (await tools.call("battery_status", {})).result.error == "no battery reading has arrived yet"
    tools.ctx.robot.on_battery(BatteryState(0.0, 14.2, float("nan")))
    assert (await tools.call("battery_status", {})).result.data == {"percent": None, "voltage": 14.2,
                                                                    "status": "discharging"}  # fmt: skip
    listed = await tools.call("list_places", {})
    assert [p["name"] for p in listed.result.data["places"]][:2] == ["BIO_ENG_LAB", "SENIOR_DESIGN"]
    described = await tools.call("describe_place", {"name": "hesse"})
    assert described.result.data["name"] == "HESSE_CENTER"


async def test_start_tour_by_places_or_theme(tools, nav) -> None:
    by_list = await tools.call("start_tour", {"places": ["the cafe", "clean rum"]})
    assert by_list.result.data["stops"] == ["GUELLY_DELLY", "CLEAN_ROOM"]
    await until(lambda: nav.tours and tools.ctx.robot.nav.state == "driving")
    assert tools.ctx.robot.nav.describe() == "on a tour, heading to GUELLY_DELLY (driving)"
    robots = await tools.call("start_tour", {"theme": "robots"})
    assert robots.result.data["stops"] == ["VALPO_ROBOTICS"]
    bad = await tools.call("start_tour", {"places": ["atlantis"]})
    assert not bad.result.ok
    assert "atlantis" in bad.result.error


async def test_services_absent_are_honest_errors(tools) -> None:
    for name, args, words in [
        ("set_goal", {"location": "cafe"}, "navigation is not running"),
        ("start_tour", {}, "not running"),
        ("where_am_i", {}, "localization is not running"),
        ("kb_search", {"query": "dean"}, "knowledge base is not running"),
        ("cancel_goal", {}, "navigation is not running"),
    ]:
        call = await tools.call(name, args)
        assert not call.result.ok, (name, call.result.error)
        assert words in call.result.error, (name, call.result.error)


async def test_kb_search_returns_passages(tools, kb) -> None:
    call = await tools.call("kb_search", {"query": "when was the college founded", "top_k": 2})
    assert call.result.data["count"] == 2
    assert "1920" in call.result.data["passages"][0]["text"]


def test_ip_addresses_are_real_interfaces(tools) -> None:
    import psutil

    from sage_robot.brain.toolbox import ip_addresses

    found = ip_addresses()
    real = {n for n, a in psutil.net_if_addrs().items() if any(x.family == socket.AF_INET for x in a)}
    assert set(found) <= real
    assert all(not a.startswith("127.") for v in found.values() for a in v)


async def test_web_search_without_a_key_is_not_available(tools, monkeypatch) -> None:
    monkeypatch.delenv("TAVILY_API_KEY", raising=False)
    call = await tools.call("web_search", {"query": "weather"})
    assert call.result.error == "web search is not available: no TAVILY_API_KEY is set"


async def test_web_search_with_a_key_over_loopback(bus, monkeypatch) -> None:
    async with ScriptedServer() as server:
        server.search_reply = {
            "answer": "Sunny.",
            "results": [{"title": "Weather", "content": "Sunny, 20 C"}],
        }
        url = server.base_url.removesuffix("/v1") + "/search"
        monkeypatch.setenv("TAVILY_API_KEY", "tvly-test")
        tools = make_tools(bus, Settings.model_validate({"llm": {"web_search_url": url}}))
        call = await tools.call("web_search", {"query": "weather in Valparaiso", "max_results": 2})
        assert call.result.data == {
            "answer": "Sunny.",
            "results": [{"title": "Weather", "content": "Sunny, 20 C"}],
        }
        assert server.search_requests == [
            ("Bearer tvly-test", {"query": "weather in Valparaiso", "max_results": 2})
        ]
        await server.close()
        down = await tools.call("web_search", {"query": "x"})
        assert "could not be reached" in down.result.error
    assert "TAVILY_API_KEY" in os.environ
