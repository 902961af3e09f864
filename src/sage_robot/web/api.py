"""REST endpoints of the operator pages: health, map image, places, goals, initial pose.

Navigation is reached through the bus (``navigate_to`` action, ``/nav/cancel``,
``/initialpose``), never by import.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import math
import re
from functools import lru_cache
from pathlib import Path
from typing import Any

from fastapi import APIRouter, Depends, HTTPException, Request
from fastapi.responses import Response, StreamingResponse

from sage_robot.core import topics
from sage_robot.core.errors import ConfigError, SageError
from sage_robot.core.log import get_logger
from sage_robot.core.msgs import Pose2D, PoseStamped, PoseWithCovariance, to_dict
from sage_robot.core.msgs.nav import NavigateGoal, PlaceList
from sage_robot.web.common import is_operator, json_body, require_operator, state_of

router = APIRouter()
INITIAL_POSE_COV = (0.25, 0.0, 0.0, 0.0, 0.25, 0.0, 0.0, 0.0, 0.07)  # x,y m², theta rad² (RViz's)
PLACES_TIMEOUT_S = 2.0
MAX_COORD_M = 10_000.0  # a pose farther than this from the origin is a typo
MAX_SHOWN_CHARS = 40  # of a bad value quoted back in an error
MJPEG_BOUNDARY = "sageframe"
KB_TITLE = re.compile(r"^#\s*(.*\S)\s*\(([A-Z0-9_]+)\)\s*$")  # "# Guelly Delly café (GUELLY_DELLY)"
CODE_NAME = re.compile(r"^[A-Z0-9_]+$")
KEEP_UPPER = re.compile(r"^(?:[A-Z]{2,3}|\d\w*|\w*\d)$")  # ECE, 3D, the 1 of LAB_1 (as js/places.js)
WORDS = {"LAB", "BAY", "BIO", "ENG", "HUB"}  # short words that are words, not acronyms

_log = get_logger("web")


def _number(body: dict[str, Any], key: str, default: float | None = None) -> float:
    value = body.get(key, default)
    try:
        number = float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else None
    except OverflowError:  # an integer past float range (json_body refuses these already)
        number = None
    if number is None or not math.isfinite(number):
        shown = repr(value) if len(repr(value)) <= MAX_SHOWN_CHARS else f"{repr(value)[:MAX_SHOWN_CHARS]}..."
        raise HTTPException(status_code=422, detail=f"{key}: expected a finite number, got {shown}")
    if abs(number) > MAX_COORD_M:
        raise HTTPException(status_code=422, detail=f"{key}: {value} is out of range")
    return number


def _pose(body: dict[str, Any]) -> Pose2D:
    return Pose2D(_number(body, "x"), _number(body, "y"), _number(body, "theta", 0.0))


@router.get("/api/health")
async def health(request: Request) -> dict[str, Any]:
    """Nodes and their state (errors only for the operator), as the launcher last published
    them on ``/sage/health``."""
    st = state_of(request)
    report = st.node.bus.latest(topics.HEALTH)
    nodes = {h.name: dataclasses.asdict(h) for h in report.nodes} if report is not None else {}
    if not is_operator(request):
        nodes = {n: {k: v for k, v in h.items() if k != "last_error"} for n, h in nodes.items()}
    return {
        "nodes": nodes,
        "simulated": st.node.clock.is_simulated,
        "time": st.node.clock.now(),
        "robot": st.node.settings.robot.name,
    }


@router.get("/api/map.png", dependencies=[Depends(require_operator)])
async def map_png(request: Request) -> Response:
    found = await state_of(request).hub.map_png()
    if found is None:
        raise HTTPException(status_code=404, detail="no map yet (is map_server or SLAM running?)")
    return Response(found[1], media_type="image/png", headers={"Cache-Control": "max-age=3600"})


def human_name(code: str) -> str:
    """A code name written as words: "GUELLY_DELLY" -> "Guelly Delly", "ECE_LAB_1" -> "ECE Lab 1"."""
    words = [w for w in re.split(r"[_\s]+", code) if w]
    return " ".join(w if KEEP_UPPER.match(w) and w not in WORDS else w[:1] + w[1:].lower() for w in words)


@lru_cache(maxsize=4)
def kb_titles(folder: Path) -> dict[str, str]:
    """Code name -> title from the knowledge base's place documents ("# Title (CODE)")."""
    titles: dict[str, str] = {}
    with contextlib.suppress(OSError):
        for doc in sorted(folder.glob("*.md")):
            with contextlib.suppress(OSError, UnicodeDecodeError):
                first = doc.read_text(encoding="utf-8").lstrip().split("\n", 1)[0]
                m = KB_TITLE.match(first)
                if m:
                    titles[m.group(2)] = m.group(1)
    return titles


def place_title(name: str, title: str = "") -> str:
    """What pages call a place: its own title, else the knowledge base's, else its name as words.
    A label that is no code name (a pose goal's "(1.0, 2.0)") stays as it is."""
    if title:
        return title
    if not CODE_NAME.match(name):
        return name
    from sage_robot.core.paths import package_data

    return kb_titles(package_data("kb", "places")).get(name) or human_name(name)


async def list_places(request: Request) -> list[dict[str, Any]]:
    """Places from navigation's service, else from the waypoints file."""
    st = state_of(request)
    bus = st.node.bus
    if bus.has_service(topics.PLACES):
        with contextlib.suppress(SageError):
            reply = await bus.call(topics.PLACES, None, timeout=PLACES_TIMEOUT_S)
            if isinstance(reply, PlaceList):
                titles = {p.name: p.title for p in await _file_places(request)}
                return [
                    _place_dict(p.name, p.pose, p.description, p.aliases, titles.get(p.name, ""))
                    for p in reply.places
                ]
    found = await _file_places(request)
    return [_place_dict(p.name, p.pose, p.description, p.aliases, p.title) for p in found]


async def _file_places(request: Request) -> list[Any]:
    from sage_robot.core.paths import waypoints_yaml
    from sage_robot.core.places import load_places

    try:
        return list(await asyncio.to_thread(load_places, waypoints_yaml(state_of(request).node.settings)))
    except ConfigError as exc:
        _log.warning("no places", error=str(exc))
        return []


def _place_dict(
    name: str, pose: Pose2D, description: str, aliases: tuple[str, ...], title: str = ""
) -> dict[str, Any]:
    return {
        "name": name,
        "title": place_title(name, title),
        "x": round(pose.x, 3),
        "y": round(pose.y, 3),
        "theta": round(pose.theta, 4),
        "description": description,
        "aliases": list(aliases),
    }


@router.get("/api/places", dependencies=[Depends(require_operator)])
async def places(request: Request) -> dict[str, Any]:
    return {"places": await list_places(request)}


@router.post("/api/goal", dependencies=[Depends(require_operator)])
async def goal(request: Request) -> dict[str, Any]:
    """Start navigation: ``{"place": name}`` or ``{"x", "y", "theta"}`` in the map frame."""
    st = state_of(request)
    body = await json_body(request)
    place = body.get("place")
    if place is not None:
        if not isinstance(place, str) or not place.strip():
            raise HTTPException(status_code=422, detail="place: expected a place name")
        nav_goal = NavigateGoal(place=place.strip())
    else:
        nav_goal = NavigateGoal(pose=_pose(body))
    if st.hub.estop:
        raise HTTPException(status_code=409, detail="e-stop is engaged: release it first")
    bus = st.node.bus
    if not bus.actions.has(topics.NAVIGATE_TO):
        raise HTTPException(status_code=503, detail="navigation is not running")
    if nav_goal.pose is not None:
        bus.publish(topics.GOAL_POSE, PoseStamped(st.node.clock.now(), "map", nav_goal.pose))
    handle = await bus.actions.send_goal(topics.NAVIGATE_TO, nav_goal)
    pose = nav_goal.pose
    st.hub.nav.sent(handle, nav_goal.place or (f"({pose.x:.1f}, {pose.y:.1f})" if pose else ""))
    _log.info("navigation goal from the operator", goal=to_dict(nav_goal))
    return {"ok": True, "goal_id": handle.goal_id}


@router.post("/api/cancel", dependencies=[Depends(require_operator)])
async def cancel(request: Request) -> dict[str, Any]:
    await state_of(request).teleop.cancel_navigation()
    return {"ok": True}


@router.post("/api/guide/stop")
async def guide_stop(request: Request) -> dict[str, Any]:
    """The kiosk face's Stop (public): a visitor ends the walk they are on. It only cancels
    navigation goals (never drives, never touches the e-stop), so it is safe for anyone at the
    robot; the request guard still refuses other sites (Origin)."""
    st = state_of(request)
    await st.teleop.cancel_navigation()
    _log.info("guided walk stopped from the face", client=request.client.host if request.client else "")
    return {"ok": True}


@router.post("/api/initial_pose", dependencies=[Depends(require_operator)])
async def initial_pose(request: Request) -> dict[str, Any]:
    """Set the localization's pose: ``{"x", "y", "theta"}`` in the map frame."""
    st = state_of(request)
    pose = _pose(await json_body(request))
    st.node.bus.publish(
        topics.INITIAL_POSE,
        PoseWithCovariance(st.node.clock.now(), "map", pose, INITIAL_POSE_COV),
    )
    _log.info("initial pose from the operator", x=pose.x, y=pose.y, theta=pose.theta)
    return {"ok": True}


@router.get("/api/video.mjpeg", dependencies=[Depends(require_operator)])
@router.get("/stream", dependencies=[Depends(require_operator)], include_in_schema=False)
async def mjpeg(request: Request) -> StreamingResponse:
    """The camera as MJPEG (multipart/x-mixed-replace), for an ``<img>`` or the seed's
    web_video_server URL ``/stream?topic=/image_raw``; latest frame, web.camera_fps at most."""
    hub = state_of(request).hub

    async def frames() -> Any:
        listener = hub.listen(("camera",))
        try:
            while not await request.is_disconnected():
                _, due = await hub.next_batch(listener)
                if due and hub.frame:
                    head = f"--{MJPEG_BOUNDARY}\r\nContent-Type: image/jpeg\r\n"
                    yield (head + f"Content-Length: {len(hub.frame)}\r\n\r\n").encode() + hub.frame + b"\r\n"
        finally:
            hub.unlisten(listener)

    return StreamingResponse(frames(), media_type=f"multipart/x-mixed-replace; boundary={MJPEG_BOUNDARY}")
