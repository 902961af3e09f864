"""Admin endpoints (operator login): places (list, add), recent logs, and the knowledge base.

Adding a place writes the waypoints file the profile names (``nav.waypoints``, else the
one beside ``nav.map``). The file shipped inside the package is never rewritten: the
admin is told to point ``nav.waypoints`` at a copy.
"""

from __future__ import annotations

import asyncio
import os
import re
from pathlib import Path
from typing import Any

from fastapi import APIRouter, Depends, FastAPI, HTTPException, Request

from sage_robot.core import topics
from sage_robot.core.config import Settings
from sage_robot.core.errors import ConfigError
from sage_robot.core.log import RECENT, get_logger
from sage_robot.core.msgs import Event, Pose2D
from sage_robot.core.paths import package_data, waypoints_yaml
from sage_robot.core.places import Place, Places, load_places, validate_places, write_places
from sage_robot.web.api import _place_dict, _pose
from sage_robot.web.common import WebState, json_body, require_operator, state_of

router = APIRouter(dependencies=[Depends(require_operator)])
PLACE_NAME = re.compile(r"^[A-Z0-9][A-Z0-9_]{0,47}$")  # the seed's waypoint names: CLEAN_ROOM
MAX_TEXT = 500  # characters of a description
MAX_ALIASES = 10
LOG_LIMIT_MAX = 500
FRESH_ODOM_WAIT_S = 1.0  # "place at the robot" with no page open: the wait for one odometry message
PLACES_CHANGED = "places_changed"  # Event kind published after the waypoints file is rewritten

_log = get_logger("web")
_places_lock = asyncio.Lock()


@router.get("/api/admin/logs")
async def logs(limit: int = 200, level: str = "") -> dict[str, Any]:
    if not 1 <= limit <= LOG_LIMIT_MAX:
        raise HTTPException(status_code=422, detail=f"limit: expected 1..{LOG_LIMIT_MAX}")
    records = list(RECENT.records)
    if level:
        records = [r for r in records if r["level"] == level.lower()]
    return {"records": records[-limit:]}


def _text(body: dict[str, Any], key: str) -> str:
    value = body.get(key, "")
    if not isinstance(value, str) or len(value) > MAX_TEXT:
        raise HTTPException(status_code=422, detail=f"{key}: expected text up to {MAX_TEXT} characters")
    return value.strip()


def _aliases(body: dict[str, Any]) -> tuple[str, ...]:
    value = body.get("aliases", [])
    if isinstance(value, str):
        value = [a for a in (s.strip() for s in value.split(",")) if a]
    if (
        not isinstance(value, list)
        or len(value) > MAX_ALIASES
        or not all(isinstance(a, str) and 0 < len(a) <= 80 for a in value)
    ):
        raise HTTPException(status_code=422, detail=f"aliases: expected up to {MAX_ALIASES} short names")
    return tuple(a.strip() for a in value)


@router.post("/api/admin/places")
async def add_place(request: Request) -> dict[str, Any]:
    """Add a place: ``{"name", "description", "aliases", "at_robot": true}`` or with ``x, y, theta``."""
    st = state_of(request)
    body = await json_body(request)
    name = body.get("name")
    if not isinstance(name, str) or not PLACE_NAME.match(name.strip()):
        raise HTTPException(
            status_code=422, detail="name: use capitals, digits and _ (like CLEAN_ROOM), up to 48"
        )
    pose = await _robot_pose(st) if body.get("at_robot") is True else _pose(body)
    place = Place(name.strip(), pose, _text(body, "description"), _aliases(body))
    path = waypoints_yaml(st.node.settings)
    where = waypoints_info(st.node.settings)
    if not where["writable"]:
        raise HTTPException(status_code=409, detail=f"{where['name']}: {where['note']}")
    async with _places_lock:
        try:
            current = await asyncio.to_thread(load_places, path) if path.exists() else Places([], str(path))
            if place.name in current:
                raise HTTPException(status_code=409, detail=f"a place named {place.name} exists already")
            updated = Places([*current, place], str(path))
            if st.hub.map_grid is not None:
                validate_places(Places([place], str(path)), st.hub.map_grid)
            await asyncio.to_thread(write_places, updated, path)
        except ConfigError as exc:
            raise HTTPException(status_code=422, detail=str(exc)) from None
    _log.info("place added", place=place.name, x=round(pose.x, 2), y=round(pose.y, 2), file=str(path))
    # map_server and the navigator re-read the file on this event; open teleop pages reload.
    st.node.bus.publish(
        topics.EVENTS,
        Event(st.node.clock.now(), "web", PLACES_CHANGED, f"{place.name} added", {"file": str(path)}),
    )
    return {"ok": True, "file": where["name"], "places": [_place_json(p) for p in updated]}


@router.get("/api/admin/places")
async def file_places(request: Request) -> dict[str, Any]:
    """The places in the waypoints file (what the admin edits; navigation may lag until it reloads)."""
    path = waypoints_yaml(state_of(request).node.settings)
    try:
        places = await asyncio.to_thread(load_places, path)
    except ConfigError as exc:
        raise HTTPException(status_code=422, detail=str(exc)) from None
    return {"file": waypoints_info(state_of(request).node.settings)["name"],
            "places": [_place_json(p) for p in places]}  # fmt: skip


def waypoints_info(settings: Settings) -> dict[str, Any]:
    """The places file for a person: a short ``name``, the full ``path``, whether added
    places can be ``writable`` into it, ``shipped`` (inside the package) and a ``note``."""
    path = waypoints_yaml(settings)
    maps = package_data("maps").resolve()
    full = path.resolve()
    shipped = full.is_relative_to(package_data().resolve())
    if shipped:
        name = str(full.relative_to(maps)) if full.is_relative_to(maps) else full.name
        return {
            "name": name, "path": str(path), "shipped": True, "writable": False,
            "note": "shipped with SAGE, read-only: to add places, copy it and set nav.waypoints "
            "in the profile to the copy",
        }  # fmt: skip
    name = f"{full.parent.name}/{full.name}" if full.parent.name else full.name
    target = full if full.exists() else full.parent
    writable = target.exists() and os.access(target, os.W_OK)
    note = "" if writable else f"cannot be written (check {Path(target)} and its permissions)"
    return {"name": name, "path": str(path), "shipped": False, "writable": writable, "note": note}


def _place_json(p: Place) -> dict[str, Any]:
    return _place_dict(p.name, p.pose, p.description, p.aliases)


async def _robot_pose(st: WebState) -> Pose2D:
    pose, frame = await st.hub.current_pose(FRESH_ODOM_WAIT_S)
    if pose is None or frame != "map":
        raise HTTPException(
            status_code=409,
            detail="the robot is not localized on the map yet; click the map to give x, y instead",
        )
    return Pose2D(*pose)


def mount_kb(app: FastAPI, st: WebState) -> None:
    """Include the knowledge base's router (``/api/kb/*``, ``/kb/admin``) when the KB is installed.

    The service is the KB node's, looked up on each request (503 while it is not running).
    """
    try:
        from sage_robot.kb.api import make_router
        from sage_robot.kb.node import KB_SERVICE
    except ImportError as exc:
        st.extras["kb_missing"] = f"the knowledge base is not installed ({exc.name or exc})"
        return
    resources = st.node.ctx.resources
    settings = st.node.settings
    app.include_router(
        make_router(
            lambda: resources.get(KB_SERVICE),
            require_operator,
            email=settings.email,
            secrets_file=settings.secrets_file or None,
        )
    )


def kb_status(st: WebState) -> str:
    """Empty when the KB answers; else why not, for a person."""
    if st.extras.get("kb_missing"):
        return str(st.extras["kb_missing"])
    from sage_robot.kb.node import KB_SERVICE  # installed: kb_missing is not set

    if st.node.ctx.resources.get(KB_SERVICE) is None:
        return "the knowledge base node is not running (add \"kb\" to the profile's nodes)"
    return ""


@router.get("/api/admin/info")
async def info(request: Request) -> dict[str, Any]:
    st = state_of(request)
    return {
        "kb": kb_status(st),
        "waypoints": waypoints_info(st.node.settings),
    }
