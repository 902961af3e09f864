"""REST endpoints of SLAM mode: save the map being built, see how mapping is going.

- ``POST /api/slam/save`` ``{"name": NAME}`` (operator only): calls the slam node's bus
  service ``/slam/save``; the files go to the node's output directory (the client cannot
  choose a path on the robot). Answers ``{"ok": true, "yaml", "pgm", "graph", "trajectory"}``.
- ``GET /api/slam/progress`` (operator only): the last ``/slam/progress`` message (scans,
  keyframes, loop closures, match score, pose), ``{"running": false}`` when no slam node runs.
- ``GET /api/slam/maps`` (operator only): the maps saved in the slam node's output directory.
- ``POST /api/slam/tour-map`` ``{"name": NAME}`` (operator only): make a saved map the tour
  map (:mod:`sage_robot.nav.slam.tour`): writes ``NAME.profile.yaml`` (and a places file
  ``NAME.waypoints.yaml`` when it has none); the next ``sage sim --profile …`` tours it.

``sage slam save NAME`` uses these from another process (the bus is in-process).
"""

from __future__ import annotations

import asyncio
from typing import Any

from fastapi import APIRouter, Depends, HTTPException, Request

from sage_robot.core.errors import SageError, ServiceError
from sage_robot.core.log import get_logger
from sage_robot.core.msgs.base import to_dict
from sage_robot.nav.slam.messages import SaveMapRequest
from sage_robot.nav.slam.node import SLAM_PROGRESS, SLAM_SAVE, maps_dir
from sage_robot.nav.slam.store import check_name
from sage_robot.nav.slam.tour import make_tour_profile, saved_maps
from sage_robot.web.common import json_body, require_operator, state_of

SAVE_TIMEOUT_S = 120.0  # a large map's pose graph and PGM take a few seconds to write (s)

router = APIRouter()
_log = get_logger("web")


@router.post("/api/slam/save", dependencies=[Depends(require_operator)])
async def save(request: Request) -> dict[str, Any]:
    """Save the running SLAM session as ``{"name": NAME}``."""
    name = await _map_name(request)
    bus = state_of(request).node.bus
    if not bus.has_service(SLAM_SAVE):
        raise HTTPException(status_code=503, detail="SLAM is not running (start `sage slam` or mode slam)")
    try:
        reply = await bus.call(SLAM_SAVE, SaveMapRequest(name), timeout=SAVE_TIMEOUT_S)
    except ServiceError as exc:
        raise HTTPException(status_code=500, detail=f"could not save the map: {exc}") from None
    _log.info("map saved for the operator", name=name, yaml=reply.yaml)
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


async def _map_name(request: Request) -> str:
    """The ``name`` of the JSON body, checked as a map name (422 otherwise)."""
    body = await json_body(request)
    name = body.get("name")
    if not isinstance(name, str) or not name.strip():
        raise HTTPException(status_code=422, detail="name: expected a map name")
    try:
        return check_name(name.strip())
    except SageError as exc:
        raise HTTPException(status_code=422, detail=str(exc)) from None


@router.get("/api/slam/maps", dependencies=[Depends(require_operator)])
async def maps(request: Request) -> dict[str, Any]:
    """The saved maps (newest first) in the directory the slam node saves to."""
    node = state_of(request).node
    directory = maps_dir(node.ctx.resources, node.settings.slam)
    return {"directory": str(directory), "maps": await asyncio.to_thread(saved_maps, directory)}


@router.post("/api/slam/tour-map", dependencies=[Depends(require_operator)])
async def tour_map(request: Request) -> dict[str, Any]:
    """Make the saved map ``{"name": NAME}`` the tour map (a profile that loads it)."""
    name = await _map_name(request)
    node = state_of(request).node
    directory = maps_dir(node.ctx.resources, node.settings.slam)
    try:
        tour = await asyncio.to_thread(make_tour_profile, node.settings, directory, name)
    except SageError as exc:
        status = 404 if not (directory / f"{name}.yaml").exists() else 422
        raise HTTPException(status_code=status, detail=str(exc)) from None
    _log.info("tour map chosen", name=name, profile=str(tour.profile))
    return {"ok": True, **tour.as_dict()}
