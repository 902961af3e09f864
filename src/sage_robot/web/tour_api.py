"""The visitor's tour on the pages: its state on ``/ws/status`` (channel ``tour``) and commands.

- ``GET /api/tour``: the tour as the pages show it (public: the face shows it to anyone).
- ``POST /api/tour/stop``: a visitor at the face ends the tour (public, like the face's
  Stop of a walk: it only ends the tour and its goal, never drives).
- ``POST /api/tour/{pause|resume|skip}``: the operator (teleop). Resume is refused while
  the e-stop is engaged.

Commands go to the brain's ``tour`` node through the bus (``/sage/tour/control``); a
command that does not fit the tour's state ("the tour is not paused") is a 409 with the
reason, a tour node that is not running a 503.
"""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Depends, HTTPException, Request

from sage_robot.core import topics
from sage_robot.core.errors import SageError
from sage_robot.core.log import get_logger
from sage_robot.core.msgs.tour import TourCommand, TourState
from sage_robot.web.common import is_operator, require_operator, state_of

router = APIRouter()
CONTROL_TIMEOUT_S = 8.0  # a command may wait for the running leg to wind down
OPERATOR_COMMANDS = ("pause", "resume", "skip")

_log = get_logger("web")


def tour_json(msg: TourState) -> dict[str, Any]:
    """The ``tour`` channel's message: phase, stops with titles, the current one, progress."""
    stops = [
        {"name": n, "title": msg.titles[i] if i < len(msg.titles) else n,
         "status": "visited" if n in msg.visited else "skipped" if n in msg.skipped else
         ("current" if i == msg.index else "ahead" if i > msg.index else "passed")}
        for i, n in enumerate(msg.stops)
    ]  # fmt: skip
    current = msg.stops[msg.index] if 0 <= msg.index < len(msg.stops) else ""
    return {
        "type": "tour",
        "phase": msg.phase.value,
        "stops": stops,
        "index": msg.index,
        "current": current,
        "current_title": stops[msg.index]["title"] if current else "",
        "minutes": round(msg.estimate_s / 60) if msg.estimate_s else None,
        "reason": msg.reason,
    }


async def _command(request: Request, command: str) -> dict[str, Any]:
    st = state_of(request)
    bus = st.node.bus
    if command == "resume" and st.hub.estop:
        raise HTTPException(status_code=409, detail="e-stop is engaged: release it first")
    if not bus.has_service(topics.TOUR_CONTROL):
        raise HTTPException(status_code=503, detail="the tour guide is not running")
    try:
        who = "operator" if is_operator(request) else "visitor"
        reply = await bus.call(topics.TOUR_CONTROL, TourCommand(command, by=who), timeout=CONTROL_TIMEOUT_S)
    except SageError as exc:
        raise HTTPException(status_code=503, detail=f"the tour guide did not answer: {exc}") from None
    if not isinstance(reply, TourState):
        raise HTTPException(status_code=502, detail="the tour guide gave an answer I do not understand")
    if not reply.ok:
        raise HTTPException(status_code=409, detail=reply.reason)
    _log.info("tour command from the pages", command=command)
    return {"ok": True, "tour": tour_json(reply)}


@router.get("/api/tour")
async def tour(request: Request) -> dict[str, Any]:
    latest = state_of(request).node.bus.latest(topics.TOUR_STATE)
    return {"tour": tour_json(latest if isinstance(latest, TourState) else TourState())}


@router.post("/api/tour/stop")
async def tour_stop(request: Request) -> dict[str, Any]:
    """The face's "End tour" (public)."""
    return await _command(request, "stop")


@router.post("/api/tour/{command}", dependencies=[Depends(require_operator)])
async def tour_command(request: Request, command: str) -> dict[str, Any]:
    if command not in OPERATOR_COMMANDS:
        known = ", ".join((*OPERATOR_COMMANDS, "stop"))
        raise HTTPException(status_code=404, detail=f"no tour command {command!r}; commands: {known}")
    return await _command(request, command)
