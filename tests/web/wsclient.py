"""Talking to the web node as a page does: WebSocket URLs, the teleop socket, bounded receives."""

from __future__ import annotations

import json
import time
from typing import Any

from websockets.sync.client import connect
from websockets.typing import Origin

WAIT_S = 10.0  # bound on opening a socket or receiving an awaited message


def ws_url(robot: Any, path: str) -> str:
    return robot.url.replace("http://", "ws://") + path


def teleop_ws(robot: Any, cookie: str, origin: str | None = None) -> Any:
    """The operator's /ws/teleop (``origin``: the Origin header to send, else the client's default)."""
    url, headers = ws_url(robot, "/ws/teleop"), {"Cookie": cookie}
    if origin:
        return connect(url, origin=Origin(origin), additional_headers=headers, open_timeout=WAIT_S)
    return connect(url, additional_headers=headers, open_timeout=WAIT_S)


def recv_json(ws: Any, kind: str, timeout: float = WAIT_S) -> dict[str, Any]:
    """The next JSON message of type ``kind`` (others are skipped); fails after ``timeout`` s."""
    deadline = time.monotonic() + timeout
    while True:
        left = deadline - time.monotonic()
        if left <= 0:
            raise AssertionError(f"timed out after {timeout:g} s waiting for a {kind!r} message")
        try:
            msg = json.loads(ws.recv(timeout=left))
        except TimeoutError:
            raise AssertionError(f"timed out after {timeout:g} s waiting for a {kind!r} message") from None
        if msg.get("type") == kind:
            return msg
