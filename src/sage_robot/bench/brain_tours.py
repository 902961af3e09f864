"""Tours planned for visitors, scored (`sage bench brain`, its ``tours`` section).

Each request below is said to the real offline brain, with the real tour node planning on the
default building's map (path lengths from the dock, where the robot stands) on a real bus.
A request is *valid* when the brain planned a tour (``plan_tour``) and the plan:

- has stops, every one a place of the building and none the dock or the restrooms;
- fits the visitor's stated time (the plan's estimate, path length / cruise speed plus the
  dwell at each stop, is at most the budget);
- answers the request: every stop is one of the places the request accepts, and the places
  it requires are there;
- is in route order: no order of its stops is shorter (every order tried);

and the visitor's "yes" then starts that tour, those stops in that order (``start_tour``,
the tour node's first leg). Navigation is a stand-in serving ``navigate_to`` (goals are
taken and keep running).
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import time
from dataclasses import dataclass
from typing import Any

from sage_robot.brain.offline import OfflineBrain
from sage_robot.brain.robot import RobotLink
from sage_robot.brain.tools import ToolContext, ToolRegistry
from sage_robot.brain.tour_runner import TourNode
from sage_robot.brain.tours import NOT_ON_TOURS, route_length
from sage_robot.core import topics
from sage_robot.core.actions import GoalContext
from sage_robot.core.bus import Bus
from sage_robot.core.config import Settings
from sage_robot.core.mapio import read_map
from sage_robot.core.msgs import Pose2D, PoseWithCovariance
from sage_robot.core.msgs.nav import NavigateGoal, NavigateResult
from sage_robot.core.msgs.tour import TourState
from sage_robot.core.node import NodeContext
from sage_robot.core.paths import map_yaml, waypoints_yaml

STANDS_AT = "DOCKING_STATION"
ROUTES_TIMEOUT_S = 120.0  # the route table is built in a thread (a few seconds)
TURN_TIMEOUT_S = 30.0
START_TIMEOUT_S = 10.0
COV = (0.01, 0.0, 0.0, 0.0, 0.01, 0.0, 0.0, 0.0, 0.01)
LABS = frozenset({
    "BIO_ENG_LAB", "SENIOR_DESIGN", "MANUFACTURING_LAB", "3D_PRINTING_LAB", "CLEAN_ROOM", "ECE_LAB_1",
    "ECE_LAB_2", "MECHATRONICS_LAB", "VALPO_ROBOTICS", "MATERIALS_TESTING_LAB", "HEAT_POWER_LAB",
    "TRANSPORTATION_LAB",
})  # fmt: skip
MAKING = frozenset({"MANUFACTURING_LAB", "3D_PRINTING_LAB"})
ANY: frozenset[str] = frozenset()  # every tour place is accepted


@dataclass(frozen=True)
class Request:
    text: str
    budget_s: float | None  # the time the visitor states
    accepted: frozenset[str]  # places a stop may be (ANY: every tour place)
    required: frozenset[str] = frozenset()  # places the plan must have


REQUESTS = (
    Request("I have ten minutes, show me the labs", 600.0, LABS),
    Request("show me the labs", None, LABS),
    Request("I like robots and 3D printing", None, frozenset({"VALPO_ROBOTICS", "3D_PRINTING_LAB"}),
            frozenset({"VALPO_ROBOTICS", "3D_PRINTING_LAB"})),
    Request("I have 5 minutes", 300.0, ANY),
    Request("we only have fifteen minutes, we love robots", 900.0, frozenset({"VALPO_ROBOTICS"}),
            frozenset({"VALPO_ROBOTICS"})),
    Request("I am interested in manufacturing and 3D printing", None, MAKING, MAKING),
    Request("I have half an hour, show me the labs", 1800.0, LABS),
    Request("I have 3 minutes, I like the clean room", 180.0, frozenset({"CLEAN_ROOM"})),
    Request("I have twenty minutes", 1200.0, ANY),
    Request("I enjoy electronics", None, frozenset({"ECE_LAB_1", "ECE_LAB_2"})),
)  # fmt: skip


async def _taken(goal: NavigateGoal, ctx: GoalContext) -> NavigateResult:
    await asyncio.Event().wait()  # taken and under way until cancelled
    return NavigateResult(True, goal.place)


def _problems(req: Request, plan: dict[str, Any], distance: Any) -> list[str]:
    stops: list[str] = plan["stops"]
    problems = []
    if not stops:
        problems.append("no stops")
    if set(stops) & NOT_ON_TOURS:
        problems.append("a stop that is no tour place")
    if req.budget_s is not None and plan["estimate_s"] > req.budget_s:
        problems.append(f"over the time: {plan['estimate_s']} s > {req.budget_s} s")
    if req.accepted and not set(stops) <= req.accepted:
        problems.append(f"stops the request did not ask for: {sorted(set(stops) - req.accepted)}")
    if not req.required <= set(stops):
        problems.append(f"missing {sorted(req.required - set(stops))}")
    best = min(route_length(o, distance) for o in itertools.permutations(stops)) if stops else 0.0
    if route_length(stops, distance) > best + 1e-6:
        problems.append("not in route order")
    return problems


async def _one(brain: OfflineBrain, node: TourNode, req: Request, session: str) -> dict[str, Any]:
    out: dict[str, Any] = {"text": req.text}
    result = await asyncio.wait_for(brain.respond(req.text, session=session), TURN_TIMEOUT_S)
    planned = [c for c in result.tool_calls if c.name == "plan_tour" and c.result.ok]
    if not planned:
        out["problems"] = [f"no plan (intent {result.intent}): {result.reply}"]
        return out
    plan = planned[0].result.data
    distance, _ = await node.distances()
    out.update(stops=plan["stops"], estimate_s=plan["estimate_s"], problems=_problems(req, plan, distance))
    yes = await asyncio.wait_for(brain.respond("yes", session=session), TURN_TIMEOUT_S)
    started = [c for c in yes.tool_calls if c.name == "start_tour" and c.result.ok]
    state = node.bus.latest(topics.TOUR_STATE)
    if not started or not isinstance(state, TourState) or list(state.stops) != plan["stops"]:
        out["problems"].append(f"'yes' did not start the plan: {yes.reply}")
    out["within_budget"] = req.budget_s is None or plan["estimate_s"] <= req.budget_s
    return out


async def _run() -> dict[str, Any]:
    settings = Settings()
    bus = Bus()
    node = TourNode(NodeContext(bus, bus.clock, settings))
    bus.actions.serve(topics.NAVIGATE_TO, _taken)
    await node.setup()
    robot = RobotLink(bus, waypoints_yaml(settings))
    try:
        dock = node.places.get(STANDS_AT).pose
        bus.publish(topics.AMCL_POSE, PoseWithCovariance(0.0, "map", Pose2D(dock.x, dock.y), COV))
        bus.declare(topics.MAP, latched=True)
        t0 = time.perf_counter()
        bus.publish(topics.MAP, read_map(map_yaml(settings)))
        while node.routes is None:
            if time.perf_counter() - t0 > ROUTES_TIMEOUT_S:
                raise TimeoutError(f"no route table after {ROUTES_TIMEOUT_S:g} s")
            await asyncio.sleep(0.05)
        routes_s = time.perf_counter() - t0
        brain = OfflineBrain(ToolRegistry(ToolContext(robot, settings)))
        rows = []
        for i, req in enumerate(REQUESTS):
            rows.append(await _one(brain, node, req, f"tour-{i}"))
            with contextlib.suppress(Exception):
                await brain.respond("stop the tour", session=f"tour-{i}")
        return {"rows": rows, "routes_s": routes_s}
    finally:
        await robot.close()
        await node.teardown()
        await node._close()
        bus.actions.unserve(topics.NAVIGATE_TO)


def run_tours() -> dict[str, Any]:
    """The ``tours`` section: counts, the plans' sizes and times, and what went wrong."""
    t0 = time.perf_counter()
    out = asyncio.run(_run())
    rows = out["rows"]
    planned = [r for r in rows if "stops" in r]
    valid = [r for r in planned if not r["problems"]]
    budgeted = [r for r, q in zip(rows, REQUESTS, strict=True) if q.budget_s is not None and "stops" in r]
    return {
        "requests": len(rows),
        "planned": len(planned),
        "valid": len(valid),
        "valid_rate": round(len(valid) / len(rows), 3),
        "with_budget": sum(q.budget_s is not None for q in REQUESTS),
        "within_budget": sum(bool(r.get("within_budget")) for r in budgeted),
        "mean_stops": round(sum(len(r["stops"]) for r in planned) / max(1, len(planned)), 2),
        "mean_estimate_min": round(sum(r["estimate_s"] for r in planned) / max(1, len(planned)) / 60, 1),
        "failures": [{"text": r["text"], "problems": r["problems"]} for r in rows if r["problems"]],
        "route_table_s": round(out["routes_s"], 2),
        "seconds": round(time.perf_counter() - t0, 1),
    }
