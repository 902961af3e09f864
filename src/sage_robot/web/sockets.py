"""WebSockets (the protocol is in docs/protocols.md).

- ``/ws/teleop`` (operator): control in, e-stop, ping; see :mod:`teleop`.
- ``/ws/status`` (public): battery, ui_state, e-stop state, ping/pong — the seed's; and for
  the kiosk face the navigation state (``nav``, with the destination's ``title``), the
  ``captions`` of recent turns, the visitor's ``tour`` and the navigator's ``social`` events.
- ``/ws/doa`` (public): speaker direction for the face's pupils.
- ``/ws/live`` (operator): the live map's layers (map, pose, scan, plan, goal, people,
  localization health, the navigator's costmap, navigation state, events).
- ``/ws/camera`` (operator): JPEG frames as binary messages, latest frame only.

Every socket checks ``Origin``; operator sockets also need the session cookie (the
handshake is refused with HTTP 403 otherwise). A bad message gets
``{"type": "error", "error": "..."}`` and the socket stays open.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import time
from typing import Any

from fastapi import APIRouter, WebSocket, WebSocketDisconnect

from sage_robot.core.log import get_logger
from sage_robot.web.auth import origin_allowed
from sage_robot.web.common import is_operator, nonfinite_field, state_of
from sage_robot.web.teleop import BadMessage, parse_control

router = APIRouter()
PING_PERIOD_S = 5.0  # server ping on /ws/status (s)
POLICY_VIOLATION = 1008  # WebSocket close code: refused (origin or login)

STATUS_CHANNELS = ("battery", "ui_state", "ui_state_seed", "estop", "nav", "captions", "tour", "social")
LIVE_CHANNELS = (
    "map", "pose", "odom", "scan", "plan", "goal", "people", "loc", "nav", "estop", "teleop",
    "battery", "ui_state", "events", "costmap",
)  # fmt: skip

_log = get_logger("web")


async def _admit(ws: WebSocket, operator: bool) -> bool:
    """Check origin (and login); refuse the handshake (HTTP 403) when not allowed."""
    st = state_of(ws)
    extra = st.node.settings.web.allowed_origins
    if not origin_allowed(ws.headers.get("origin"), ws.headers.get("host"), extra):
        _log.warning("websocket refused: foreign origin", origin=ws.headers.get("origin"), path=ws.url.path)
        await ws.close(code=POLICY_VIOLATION)
        return False
    if operator and not is_operator(ws):
        _log.warning("websocket refused: not logged in", path=ws.url.path)
        await ws.close(code=POLICY_VIOLATION)
        return False
    await ws.accept()
    return True


def _decode(text: str | None) -> dict[str, Any]:
    if text is None:
        raise BadMessage("expected a JSON text message")
    try:
        msg = json.loads(text)
    except json.JSONDecodeError as exc:
        raise BadMessage(f"not valid JSON: {exc.msg}") from None
    except (ValueError, RecursionError) as exc:  # an integer of over 4300 digits, deep nesting
        raise BadMessage(f"not usable JSON: {exc}") from None
    if not isinstance(msg, dict) or not isinstance(msg.get("type"), str):
        raise BadMessage('expected a JSON object with a "type"')
    bad = nonfinite_field(msg)
    if bad is not None:
        raise BadMessage(f"{bad}: expected a finite number")
    return msg


async def _pump(ws: WebSocket, channels: tuple[str, ...], camera: bool = False) -> None:
    """Send the hub's changes on ``channels`` to this client until it goes away."""
    hub = state_of(ws).hub
    listener = hub.listen(channels + (("camera",) if camera else ()))
    try:
        while True:
            messages, frame_due = await hub.next_batch(listener)
            for m in messages:
                if isinstance(m, bytes):
                    await ws.send_bytes(m)
                else:
                    await ws.send_json(m)
            if frame_due and hub.frame:
                await ws.send_bytes(hub.frame)
    except (WebSocketDisconnect, RuntimeError, asyncio.CancelledError):
        raise
    except Exception:
        _log.exception("websocket sender failed", path=ws.url.path)
        raise
    finally:
        hub.unlisten(listener)


async def _serve(ws: WebSocket, channels: tuple[str, ...], handle: Any, camera: bool = False) -> None:
    """Run the pump and the receive loop together; ``handle(msg)`` returns a reply or None."""
    pump = asyncio.get_running_loop().create_task(_pump(ws, channels, camera))
    try:
        while True:
            raw = await ws.receive()
            if raw["type"] == "websocket.disconnect":
                return
            try:
                msg = _decode(raw.get("text"))
                reply = await handle(msg)
            except (ValueError, OverflowError) as exc:  # BadMessage is a ValueError
                reply = {"type": "error", "error": _bad_message_text(exc)}
            if reply is not None:
                await ws.send_json(reply)
    except (WebSocketDisconnect, RuntimeError):
        return
    finally:
        pump.cancel()
        with contextlib.suppress(asyncio.CancelledError, Exception):
            await pump


def _bad_message_text(exc: Exception) -> str:
    """What the client is told: a BadMessage's own text, else what kind of value failed."""
    if isinstance(exc, BadMessage):
        return str(exc)
    _log.warning("websocket message refused", error=f"{type(exc).__name__}: {exc}")
    if isinstance(exc, OverflowError):
        return "a number is out of range"
    return f"bad message: {exc}"


async def _common(msg: dict[str, Any]) -> dict[str, Any] | None:
    kind = msg["type"]
    if kind == "ping":
        return {"type": "pong", "t": msg.get("t")}
    if kind == "pong":
        return None
    raise BadMessage(f"unknown message type {kind!r}")


@router.websocket("/ws/teleop")
async def ws_teleop(ws: WebSocket) -> None:
    if not await _admit(ws, operator=True):
        return
    teleop = state_of(ws).teleop
    client = object()

    async def handle(msg: dict[str, Any]) -> dict[str, Any] | None:
        kind = msg["type"]
        if kind == "control":
            teleop.control(client, *parse_control(msg))
            return None
        if kind == "estop":
            engaged = msg.get("engaged")
            if not isinstance(engaged, bool):
                raise BadMessage('estop: "engaged" must be true or false')
            await teleop.set_estop(engaged, "operator")
            return {"type": "estop", "engaged": teleop.estop}
        return await _common(msg)

    try:
        await _serve(ws, ("estop", "teleop", "battery", "ui_state"), handle)
    finally:
        teleop.release_client(client)


@router.websocket("/ws/status")
async def ws_status(ws: WebSocket) -> None:
    if not await _admit(ws, operator=False):
        return

    async def pinger() -> None:
        while True:
            await asyncio.sleep(PING_PERIOD_S)
            await ws.send_json({"type": "ping", "t": round(time.time(), 3)})

    task = asyncio.get_running_loop().create_task(pinger())
    try:
        await _serve(ws, STATUS_CHANNELS, _common)
    finally:
        task.cancel()


@router.websocket("/ws/doa")
async def ws_doa(ws: WebSocket) -> None:
    if not await _admit(ws, operator=False):
        return
    await _serve(ws, ("doa",), _common)


@router.websocket("/ws/audio")
async def ws_audio(ws: WebSocket) -> None:
    """The robot's speech (public, for the kiosk in simulation): binary messages of a
    uint32 LE sample rate followed by int16 LE mono PCM, and ``{"type": "audio_end"}``."""
    if not await _admit(ws, operator=False):
        return
    await _serve(ws, ("audio",), _common)


@router.websocket("/ws/live")
async def ws_live(ws: WebSocket) -> None:
    if not await _admit(ws, operator=True):
        return
    await _serve(ws, LIVE_CHANNELS, _common)


@router.websocket("/ws/camera")
async def ws_camera(ws: WebSocket) -> None:
    if not await _admit(ws, operator=True):
        return
    await _serve(ws, (), _common, camera=True)
