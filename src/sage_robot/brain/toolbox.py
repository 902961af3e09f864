"""The robot's tools (registered in :data:`sage_robot.brain.tools.TOOLS`).

Each tool's arguments are one :class:`ToolArgs` model: the schema the LLM is given is
generated from it and the registry validates the LLM's arguments with it before the tool
runs. Navigation and the knowledge base are reached through :class:`RobotLink` (the bus);
web search through Tavily's HTTP API when a key is set. Every failure a visitor can
cause, or a missing service, is a :class:`ToolResult` error, never an exception.
"""

from __future__ import annotations

import math
import socket
from typing import Annotated, Any, Literal

from pydantic import Field

from sage_robot.brain import tour_tools
from sage_robot.brain.matching import match_place, places_with_theme
from sage_robot.brain.readiness import DOCK
from sage_robot.brain.robot import Outcome
from sage_robot.brain.tools import NoArgs, ToolArgs, ToolContext, ToolResult, tool
from sage_robot.brain.tours import SECONDS_PER_MINUTE
from sage_robot.core.config import read_secret
from sage_robot.core.msgs.tour import TourCommand, TourRequest
from sage_robot.core.places import Place, Places

KB_PASSAGE_CHARS = 700  # passage text handed to the model per hit
WEB_TIMEOUT_S = 10.0
WEB_CONTENT_CHARS = 500  # per web result
MAX_TOUR_STOPS = 8
KB_TOP_K_MAX = 10
WEB_RESULTS_MAX = 8
TOUR_PLACES_MAX = 12  # places a model may name for one tour (the first MAX_TOUR_STOPS are kept)
TOUR_MINUTES_MAX = 240.0  # a visitor's time for a tour beyond this is a mistake


class SetGoalArgs(ToolArgs):
    location: str = Field(min_length=1, description="Place name")


class KbSearchArgs(ToolArgs):
    query: str = Field(min_length=1)
    top_k: int = Field(3, ge=1, le=KB_TOP_K_MAX)


class WebSearchArgs(ToolArgs):
    query: str = Field(min_length=1)
    max_results: int = Field(3, ge=1, le=WEB_RESULTS_MAX)


class DescribePlaceArgs(ToolArgs):
    name: str = Field(min_length=1)


class StartTourArgs(ToolArgs):
    places: list[Annotated[str, Field(min_length=1)]] | None = Field(None, max_length=TOUR_PLACES_MAX)
    theme: str | None = None


def _place_list(places: Places) -> list[dict[str, str]]:
    return [{"name": p.name, "description": p.description} for p in places]


async def _resolve(ctx: ToolContext, text: str) -> tuple[Place | None, Places]:
    places = await ctx.robot.places()
    if text in places:
        return places.get(text), places
    found = match_place(text, places)
    return (found.place if found else None), places


def _not_started(out: Outcome) -> ToolResult:
    """A drive or tour that did not start: the reason, and that no goal is running, so a
    model reading the result can not tell the visitor to follow it."""
    refused = out.refused.value if out.refused is not None else "navigation"
    return ToolResult.fail(out.reason, goal_started=False, refused=refused)


def _unknown_place(text: str, places: Places) -> ToolResult:
    if not len(places):
        return ToolResult.fail(f"I know of no place called {text!r}: no places are loaded")
    return ToolResult.fail(
        f"there is no place matching {text!r}; known places: {', '.join(places.names())}",
        places=_place_list(places),
    )


@tool(
    "set_goal",
    "Start driving to a named place (non-blocking: returns at once; an arrival event follows). "
    "One goal at a time. Accepts a place name, an alias or a description. An error means "
    "the robot is NOT moving (e-stop, battery, lost, navigation down): say why, never 'follow me'.",
    SetGoalArgs,
)
async def set_goal(ctx: ToolContext, args: SetGoalArgs) -> ToolResult:
    place, places = await _resolve(ctx, args.location)
    if place is None:
        return _unknown_place(args.location, places)
    out = await ctx.robot.navigate(place)
    if not out.ok:
        return _not_started(out)
    return ToolResult(
        True,
        {"status": "navigating", "goal_started": True, "place": place.name, "description": place.description},
    )


@tool("cancel_goal", "Stop the current navigation goal or tour.", NoArgs)
async def cancel_goal(ctx: ToolContext, args: NoArgs) -> ToolResult:
    out = await ctx.robot.cancel()
    return ToolResult(True, dict(out.data)) if out.ok else ToolResult.fail(out.reason)


@tool(
    "kb_search",
    "Search the university's local knowledge base. Use it first for questions about the "
    "university, the college of engineering, its programs, people and buildings.",
    KbSearchArgs,
)
async def kb_search(ctx: ToolContext, args: KbSearchArgs) -> ToolResult:
    out = await ctx.robot.kb_search(args.query, args.top_k)
    if not out.ok:
        return ToolResult.fail(out.reason)
    hits = [
        {
            "text": p.text[:KB_PASSAGE_CHARS], "title": p.title, "section": p.section, "source": p.source,
            "score": round(p.score, 3), "similarity": round(p.similarity, 3),
        }
        for p in out.data
    ]
    return ToolResult(True, {"passages": hits, "count": len(hits)})


@tool(
    "web_search",
    "Search the internet (general knowledge, current events). Only when the knowledge base has no answer.",
    WebSearchArgs,
)
async def web_search(ctx: ToolContext, args: WebSearchArgs) -> ToolResult:
    import httpx

    llm = ctx.settings.llm
    key = read_secret(llm.web_search_key_env, ctx.settings.secrets_file or None)
    if key is None:
        return ToolResult.fail(f"web search is not available: no {llm.web_search_key_env} is set")
    body = {"query": args.query, "max_results": args.max_results}
    headers = {"Authorization": f"Bearer {key.get_secret_value()}"}
    try:
        async with httpx.AsyncClient(timeout=WEB_TIMEOUT_S) as client:
            reply = await client.post(llm.web_search_url, json=body, headers=headers)
    except httpx.HTTPError as exc:
        return ToolResult.fail(f"web search could not be reached: {type(exc).__name__}")
    if reply.status_code != 200:
        return ToolResult.fail(f"web search answered HTTP {reply.status_code}")
    try:
        data = reply.json()
        results = [
            {"title": r.get("title", ""), "content": str(r.get("content", ""))[:WEB_CONTENT_CHARS]}
            for r in data.get("results", [])
        ]
    except (ValueError, AttributeError, TypeError):
        return ToolResult.fail("web search gave an answer I could not read")
    out: dict[str, Any] = {"results": results}
    if data.get("answer"):
        out["answer"] = data["answer"]
    return ToolResult(True, out)


def ip_addresses() -> dict[str, list[str]]:
    """IPv4 addresses of the machine's interfaces, loopback left out."""
    try:
        import psutil
    except ImportError:
        psutil = None
    found: dict[str, list[str]] = {}
    if psutil is not None:
        for name, addrs in psutil.net_if_addrs().items():
            v4 = [a.address for a in addrs if a.family == socket.AF_INET and not a.address.startswith("127.")]
            if v4:
                found[name] = v4
        return found
    try:  # no psutil: the address the default route would use (no packet is sent)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.connect(("192.0.2.1", 9))
            found["default"] = [s.getsockname()[0]]
    except OSError:
        pass
    return found


@tool("get_ip_address", "The robot's network addresses, to find it on the network.", NoArgs)
async def get_ip_address(ctx: ToolContext, args: NoArgs) -> ToolResult:
    found = ip_addresses()
    if not found:
        return ToolResult.fail("the robot has no network address right now")
    return ToolResult(True, {"interfaces": found})


@tool("where_am_i", "Where the robot is now: the nearest named place and how far from it.", NoArgs)
async def where_am_i(ctx: ToolContext, args: NoArgs) -> ToolResult:
    out = await ctx.robot.where_am_i()
    if not out.ok:
        return ToolResult.fail(out.reason)
    w = out.data
    if not w.nearest_place or math.isnan(w.distance_m):
        return ToolResult.fail("the robot does not know where it is yet (no pose estimate)")
    return ToolResult(
        True,
        {
            "nearest_place": w.nearest_place,
            "distance_m": round(w.distance_m, 1),
            "localized": w.localized,
            "navigation": ctx.robot.status(),
        },
    )


@tool("battery_status", "The robot's battery: charge in percent, voltage and whether charging.", NoArgs)
async def battery_status(ctx: ToolContext, args: NoArgs) -> ToolResult:
    b = ctx.robot.battery
    if b is None:
        return ToolResult.fail("no battery reading has arrived yet")
    pct = None if math.isnan(b.percentage) else round(100 * b.percentage)
    return ToolResult(True, {"percent": pct, "voltage": round(b.voltage, 2), "status": b.status.value})


@tool("list_places", "Every place the robot can go, with a description.", NoArgs)
async def list_places(ctx: ToolContext, args: NoArgs) -> ToolResult:
    places = await ctx.robot.places()
    return ToolResult(True, {"places": _place_list(places)})


@tool(
    "describe_place",
    "What a place is: its description and other names.",
    DescribePlaceArgs,
)
async def describe_place(ctx: ToolContext, args: DescribePlaceArgs) -> ToolResult:
    place, places = await _resolve(ctx, args.name)
    if place is None:
        return _unknown_place(args.name, places)
    data = {"name": place.name, "description": place.description, "aliases": list(place.aliases)}
    if place.dwell_text:
        data["talking_points"] = place.dwell_text
    return ToolResult(True, data)


def tour_stops(places: Places, names: list[str] | None, theme: str | None) -> tuple[list[Place], list[str]]:
    """The tour's places (and the names that matched nothing) from a list or a theme."""
    unknown: list[str] = []
    if names:
        stops = []
        for n in names:
            found = places.get(n) if n in places else None
            m = found or (hit.place if (hit := match_place(n, places)) else None)
            if m is None:
                unknown.append(n)
            elif m not in stops:
                stops.append(m)
    elif theme:
        stops = places_with_theme(theme, places)
    else:
        stops = list(places)
    stops = [p for p in stops if p.name != DOCK and p.name != "BATHROOMS"] or stops
    return stops[:MAX_TOUR_STOPS], unknown


@tool(
    "start_tour",
    "Start a guided tour through several places (non-blocking). Give the places in order, or a "
    "theme such as 'labs' or 'robotics', or neither for the standard tour. An error means no "
    "tour started: say why.",
    StartTourArgs,
)
async def start_tour(ctx: ToolContext, args: StartTourArgs) -> ToolResult:
    places = await ctx.robot.places()
    stops, unknown = tour_stops(places, args.places, args.theme)
    if unknown:
        return _unknown_place(", ".join(unknown), places)
    if not stops:
        return ToolResult.fail(f"no place fits the theme {args.theme!r}", places=_place_list(places))
    if tour_tools.runner_up(ctx.robot):  # the tour node: route order, pause/skip/resume, on the pages
        refused = ctx.robot.readiness().refuse_tour()
        if refused is not None:
            return ToolResult.fail(refused[1], goal_started=False, refused=refused[0].value)
        speed = ctx.settings.robot.max_linear_mps
        state = await tour_tools.start_on_runner(ctx.robot, [p.name for p in stops], bool(args.places), speed)
        if isinstance(state, str):
            return ToolResult.fail(state, goal_started=False, refused="navigation")
        return ToolResult(True, {"status": "touring", "goal_started": True, "stops": list(state.stops)})
    out = await ctx.robot.tour([p.name for p in stops])
    if not out.ok:
        return _not_started(out)
    return ToolResult(True, {"status": "touring", "goal_started": True, "stops": [p.name for p in stops]})


class PlanTourArgs(ToolArgs):
    interests: str | None = Field(None, max_length=200, description="what the visitor wants to see")
    places: list[str] | None = Field(None, max_length=TOUR_PLACES_MAX, description="places the visitor named")
    minutes: float | None = Field(None, gt=0, le=TOUR_MINUTES_MAX, description="the time the visitor has")


class TourControlArgs(ToolArgs):
    command: Literal["pause", "resume", "skip", "stop"] = Field(description="what to do with the tour")


@tool(
    "plan_tour",
    "Plan a tour for the visitor (nothing moves): the places for their interests and time, in "
    "route order, with the minutes it takes. Say the plan and ask; when they agree, call "
    "start_tour with the plan's stops as places.",
    PlanTourArgs,
)
async def plan_tour(ctx: ToolContext, args: PlanTourArgs) -> ToolResult:
    budget = (args.minutes or 0.0) * SECONDS_PER_MINUTE
    request = TourRequest(args.interests or "", tuple(args.places or ()), budget)
    plan = await tour_tools.request_plan(ctx.robot, request, ctx.settings.robot.max_linear_mps)
    if not plan.ok:
        return ToolResult.fail(plan.reason, **({"left_out": list(plan.dropped)} if plan.dropped else {}))
    return ToolResult(True, tour_tools.plan_data(plan))


@tool("tour_control", "Pause, resume, skip the current stop of, or stop the running tour.", TourControlArgs)
async def tour_control(ctx: ToolContext, args: TourControlArgs) -> ToolResult:
    if args.command == "resume" and tour_tools.runner_up(ctx.robot):
        refused = ctx.robot.readiness().refuse_tour()
        if refused is not None:
            return ToolResult.fail(refused[1], refused=refused[0].value)
    state = await tour_tools.command(ctx.robot, TourCommand(args.command, by="brain"))
    if isinstance(state, str):
        return ToolResult.fail(state)
    return ToolResult(True, tour_tools.state_data(state))
