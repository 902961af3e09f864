"""The tool registry: schemas, errors as values, and each tool over the bus or loopback HTTP."""

from __future__ import annotations

import os
import socket

import pytest

from sage_robot.brain.scripted import ScriptedServer
from sage_robot.brain.tools import TOOLS, ToolRegistry
from sage_robot.core.config import Settings
from sage_robot.core.msgs import BatteryState
from sage_robot.core.paths import package_data

from .conftest import make_tools, until

EXPECTED = {"set_goal", "cancel_goal", "kb_search", "web_search", "get_ip_address", "where_am_i",
            "battery_status", "list_places", "start_tour", "describe_place"}  # fmt: skip


@pytest.fixture
def tools(bus, settings) -> ToolRegistry:
    return make_tools(bus, settings, package_data("brain", "places.yaml"))


def test_every_tool_has_a_valid_openai_spec(tools) -> None:
    assert set(tools.tools) == EXPECTED
    for spec in tools.specs():
        fn = spec["function"]
        assert spec["type"] == "function" and fn["description"] and fn["parameters"]["type"] == "object"


def test_unknown_tool_names_in_a_registry_are_refused(tools) -> None:
    with pytest.raises(ValueError, match="unknown tool"):
        ToolRegistry(tools.ctx, ["set_goal", "teleport"])
    with pytest.raises(ValueError, match="registered twice"):
        from sage_robot.brain.tools import no_args, tool

        tool("set_goal", "again", no_args())(TOOLS["set_goal"].fn)


async def test_bad_arguments_are_errors_not_exceptions(tools) -> None:
    cases = [
        ("set_goal", "not json", "not valid JSON"),
        ("set_goal", "[1, 2]", "must be a JSON object"),
        ("set_goal", {"location": 3}, "location: 3 is not of type 'string'"),
        ("set_goal", {"location": "x", "speed": 9}, "Additional properties"),
        ("kb_search", {"query": ""}, "should be non-empty"),
        ("teleport", {}, "no tool named"),
    ]
    for name, args, words in cases:
        call = await tools.call(name, args)
        assert not call.result.ok and words in call.result.error, (name, call.result.error)


async def test_set_goal_unknown_place_lists_the_places(tools, nav) -> None:
    call = await tools.call("set_goal", '{"location": "the moon"}')
    assert not call.result.ok and "CLEAN_ROOM" in call.result.error
    assert len(call.result.data["places"]) == 16 and nav.goals == []


async def test_set_goal_is_non_blocking_and_cancel_goal_stops_it(tools, nav) -> None:
    call = await tools.call("set_goal", {"location": "Guelly Deli"})
    assert call.result.data["status"] == "navigating" and call.result.data["place"] == "GUELLY_DELLY"
    assert call.result.data["description"].startswith("Engineering student café")
    await until(lambda: nav.goals)
    stop = await tools.call("cancel_goal", {})
    assert stop.result.data == {"stopped": True, "was_going_to": "GUELLY_DELLY"} and nav.cancels == 1


async def test_where_am_i_battery_and_places(tools, nav) -> None:
    where = await tools.call("where_am_i", {})
    assert where.result.data["nearest_place"] == "GUELLY_DELLY" and where.result.data["localized"]
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
    assert not bad.result.ok and "atlantis" in bad.result.error


async def test_services_absent_are_honest_errors(tools) -> None:
    for name, args, words in [
        ("set_goal", {"location": "cafe"}, "navigation is not running"),
        ("start_tour", {}, "not running"),
        ("where_am_i", {}, "localization is not running"),
        ("kb_search", {"query": "dean"}, "knowledge base is not running"),
        ("cancel_goal", {}, "navigation is not running"),
    ]:
        call = await tools.call(name, args)
        assert not call.result.ok and words in call.result.error, (name, call.result.error)


async def test_kb_search_returns_passages(tools, kb) -> None:
    call = await tools.call("kb_search", {"query": "when was the college founded", "top_k": 2})
    assert call.result.data["count"] == 2 and "1920" in call.result.data["passages"][0]["text"]


def test_ip_addresses_are_real_interfaces(tools) -> None:
    import psutil

    from sage_robot.brain.toolbox import ip_addresses

    found = ip_addresses()
    real = {n for n, a in psutil.net_if_addrs().items() if any(x.family == socket.AF_INET for x in a)}
    assert set(found) <= real and all(not a.startswith("127.") for v in found.values() for a in v)


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
