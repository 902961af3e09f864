"""What the web handlers share: the state on ``app.state.web``, login checks, JSON bodies."""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass, field
from typing import Any

from fastapi import HTTPException, Request, WebSocket

from sage_robot.web.auth import SESSION_COOKIE, RateLimiter, Sessions

LOGIN_RATE_PER_MIN = 10.0  # password attempts per client address
LOGIN_BURST = 5
TALK_RATE_PER_MIN = 20.0  # visitor questions per client address
TALK_BURST = 5
MAX_FINITE_FLOAT = sys.float_info.max  # JSON integers beyond this cannot become a float


@dataclass
class WebState:
    """What the request handlers share."""

    node: Any  # the WebNode (bus, clock, settings, ctx.resources)
    hub: Any
    teleop: Any
    sessions: Sessions
    login_limiter: RateLimiter = field(
        default_factory=lambda: RateLimiter(LOGIN_RATE_PER_MIN, LOGIN_BURST)
    )
    talk_limiter: RateLimiter = field(default_factory=lambda: RateLimiter(TALK_RATE_PER_MIN, TALK_BURST))
    extras: dict[str, Any] = field(default_factory=dict)


def state_of(conn: Request | WebSocket) -> WebState:
    return conn.app.state.web  # type: ignore[no-any-return]


def client_key(conn: Request | WebSocket) -> str:
    return conn.client.host if conn.client else "unknown"


def is_operator(conn: Request | WebSocket) -> bool:
    return state_of(conn).sessions.valid(conn.cookies.get(SESSION_COOKIE))


def require_operator(request: Request) -> None:
    """FastAPI dependency: 401 unless the request carries a valid operator session."""
    if not is_operator(request):
        raise HTTPException(status_code=401, detail="log in as the operator first (/login)")


def nonfinite_field(value: Any) -> str | None:
    """The path (``x``, ``poses[2].y``) of the first number in decoded JSON that is not a
    finite float (``1e400``, ``NaN``, an integer past float range), or None."""
    stack: list[tuple[str, Any]] = [("", value)]
    while stack:
        path, item = stack.pop()
        if isinstance(item, dict):
            stack.extend(reversed([(f"{path}.{k}" if path else str(k), v) for k, v in item.items()]))
        elif isinstance(item, list):
            stack.extend(reversed([(f"{path}[{i}]", v) for i, v in enumerate(item)]))
        elif not _finite(item):
            return path or "body"
    return None


def _finite(item: Any) -> bool:
    if isinstance(item, float):
        return math.isfinite(item)
    if isinstance(item, int) and not isinstance(item, bool):
        return abs(item) <= MAX_FINITE_FLOAT
    return True


async def json_body(request: Request) -> dict[str, Any]:
    """The request's JSON object, or a 400 that says what is wrong; a number that is not a
    finite float gets a 422 naming its field."""
    try:
        body = await request.json()
    except Exception:
        raise HTTPException(status_code=400, detail="expected a JSON body") from None
    if not isinstance(body, dict):
        raise HTTPException(status_code=400, detail="expected a JSON object")
    bad = nonfinite_field(body)
    if bad is not None:
        raise HTTPException(status_code=422, detail=f"{bad}: expected a finite number")
    return body
