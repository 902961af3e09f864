"""REST endpoints of SLAM mode: save the map being built, see how mapping is going.

- ``POST /api/slam/save`` ``{"name": NAME}`` (operator only): calls the slam node's bus
  service ``/slam/save``; the files go to the node's output directory (the client cannot
  choose a path on the robot). Answers ``{"ok": true, "yaml", "pgm", "graph", "trajectory"}``.
- ``GET /api/slam/progress`` (operator only): the last ``/slam/progress`` message (scans,
  keyframes, loop closures, match score, pose), ``{"running": false}`` when no slam node runs.

``sage slam save NAME`` uses these from another process (the bus is in-process).
"""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Depends, HTTPException, Request

from sage_robot.core.errors import SageError, ServiceError
from sage_robot.core.log import get_logger
from sage_robot.core.msgs.base import to_dict
from sage_robot.nav.slam.messages import SaveMapRequest
from sage_robot.nav.slam.node import SLAM_PROGRESS, SLAM_SAVE
from sage_robot.nav.slam.store import check_name
from sage_robot.web.common import json_body, require_operator, state_of

SAVE_TIMEOUT_S = 120.0  # a large map's pose graph and PGM take a few seconds to write (s)

router = APIRouter()
_log = get_logger("web")


@router.post("/api/slam/save", dependencies=[Depends(require_operator)])
async def save(request: Request) -> dict[str, Any]:
    """Save the running SLAM session as ``{"name": NAME}``."""
    body = await json_body(request)
    name = body.get("name")
    if not isinstance(name, str) or not name.strip():
        raise HTTPException(status_code=422, detail="name: expected a map name")
    try:
        check_name(name.strip())
    except SageError as exc:
        raise HTTPException(status_code=422, detail=str(exc)) from None
    bus = state_of(request).node.bus
    if not bus.has_service(SLAM_SAVE):
        raise HTTPException(status_code=503, detail="SLAM is not running (start `sage slam` or mode slam)")
    try:
        reply = await bus.call(SLAM_SAVE, SaveMapRequest(name.strip()), timeout=SAVE_TIMEOUT_S)
    except ServiceError as exc:
        raise HTTPException(status_code=500, detail=f"could not save the map: {exc}") from None
    _log.info("map saved for the operator", name=name.strip(), yaml=reply.yaml)
    paths = {k: v for k, v in to_dict(reply).items() if k != "type"}
    return {"ok": True, **paths}


@router.get("/api/slam/progress", dependencies=[Depends(require_operator)])
async def progress(request: Request) -> dict[str, Any]:
    """How mapping is going: the last ``/slam/progress``."""
    bus = state_of(request).node.bus
    running = bus.has_service(SLAM_SAVE)
    last = bus.latest(SLAM_PROGRESS)
    if last is None:
        return {"running": running}
    data = {k: v for k, v in to_dict(last).items() if k != "type"}
    return {"running": running, **data}
