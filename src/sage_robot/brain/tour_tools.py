"""What the tour tools do (``plan_tour``, ``tour_control`` and ``start_tour``'s way through the
tour node; the tools themselves are in :mod:`sage_robot.brain.toolbox`).

With the ``tour`` node running (:mod:`sage_robot.brain.tour_runner`), plans use its path
lengths on the map and tours run there (pausable, shown on the pages); without it a plan
uses straight lines from the robot and ``start_tour`` falls back to the navigator's ``tour``
action. A model plans, says the plan, and on the visitor's consent calls ``start_tour`` with
the plan's places: the same tools the offline brain uses. Expected failures come back as a
reason (a ``str``), never an exception.
"""

from __future__ import annotations

from typing import Any

from sage_robot.brain import tours
from sage_robot.brain.robot import RobotLink
from sage_robot.brain.tours import (
    CRUISE_FRACTION,
    DWELL_S,
    SECONDS_PER_MINUTE,
    Candidate,
    candidates,
    interests_of,
    minutes,
    named_places,
    straight_line,
)
from sage_robot.core import topics
from sage_robot.core.errors import ServiceError
from sage_robot.core.msgs import to_dict
from sage_robot.core.msgs.tour import TourCommand, TourPlan, TourRequest, TourState

PLAN_TIMEOUT_S = 5.0  # the tour node's plan (one path search from the robot)
CONTROL_TIMEOUT_S = 8.0  # a command may wait for a leg to wind down


def runner_up(robot: RobotLink) -> bool:
    return robot.bus.has_service(topics.TOUR_CONTROL)


def plan_data(plan: TourPlan) -> dict[str, Any]:
    """A plan as the model (and `sage ask --json`) reads it."""
    return {
        "stops": [s.name for s in plan.stops],
        "titles": [s.title for s in plan.stops],
        "minutes": minutes(plan.estimate_s),
        "estimate_s": plan.estimate_s,
        "drive_m": plan.drive_m,
        "budget_minutes": round(plan.budget_s / SECONDS_PER_MINUTE, 1) if plan.budget_s else None,
        "left_out": list(plan.dropped),
        "distances": plan.distances,
    }


def state_data(state: TourState) -> dict[str, Any]:
    data = to_dict(state)
    return {k: data[k] for k in ("phase", "stops", "index", "visited", "skipped")}


async def local_plan(robot: RobotLink, request: TourRequest, max_linear_mps: float) -> TourPlan:
    """A plan without the tour node: straight lines from the robot's pose (if known)."""
    places = await robot.places()
    named, unknown = named_places(list(request.places), places)
    if unknown:
        return TourPlan(False, reason=f"there is no place matching {', '.join(unknown)}")
    chosen = [Candidate(p, float("inf"), "") for p in named]
    interests = interests_of(request.interests)
    if interests or not named:
        chosen += [c for c in candidates(places, interests) if c.place not in named]
    where = await robot.where_am_i()
    start = (where.data.pose.x, where.data.pose.y) if where.ok and where.data.localized else None
    distance = straight_line(places, start)
    budget = request.budget_s or None
    speed = CRUISE_FRACTION * max_linear_mps
    return tours.plan_tour(chosen, distance, speed, budget, DWELL_S, distances="straight-line")


async def request_plan(robot: RobotLink, request: TourRequest, max_linear_mps: float) -> TourPlan:
    """The tour node's plan, else a local one."""
    if robot.bus.has_service(topics.TOUR_PLAN):
        try:
            reply = await robot.bus.call(topics.TOUR_PLAN, request, timeout=PLAN_TIMEOUT_S)
        except ServiceError as exc:
            return TourPlan(False, reason=f"the tour planner failed: {exc}")
        if isinstance(reply, TourPlan):
            return reply
    return await local_plan(robot, request, max_linear_mps)


async def command(robot: RobotLink, cmd: TourCommand) -> TourState | str:
    """The tour node's state after ``cmd``, or why it was not done."""
    if not runner_up(robot):
        return "the tour guide is not running right now"
    try:
        reply = await robot.bus.call(topics.TOUR_CONTROL, cmd, timeout=CONTROL_TIMEOUT_S)
    except ServiceError as exc:
        return f"the tour guide did not answer: {exc}"
    if not isinstance(reply, TourState):
        return "the tour guide gave an answer I do not understand"
    return reply if reply.ok else reply.reason


async def start_on_runner(
    robot: RobotLink, names: list[str], in_order: bool, max_linear_mps: float
) -> TourState | str:
    """Start a tour on the tour node (readiness was checked): the places as given, or in
    route order when they came from a theme."""
    estimate = 0.0
    if not in_order:
        plan = await request_plan(robot, TourRequest(places=tuple(names)), max_linear_mps)
        if plan.ok:
            names, estimate = [s.name for s in plan.stops], plan.estimate_s
    return await command(robot, TourCommand("start", tuple(names), estimate_s=estimate, by="brain"))
