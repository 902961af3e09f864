"""The HTTP door of the web server: Origin and Content-Type of state-changing requests,
and request body limits counted on the bytes actually received.

A pure ASGI middleware (:class:`RequestGuard`), so nothing in the routers needs to know:

- **Origin**: a ``POST``/``PUT``/``PATCH``/``DELETE`` whose ``Origin`` header is neither
  this server's own (``Origin`` host:port = ``Host``) nor listed in ``web.allowed_origins``
  gets 403 (cross-site request forgery). No ``Origin``: a client that is not a browser.
- **Content-Type**: such a request with a body must say the type its endpoint reads:
  ``multipart/form-data`` for an endpoint with ``File``/``Form`` parameters, else
  ``application/json`` (or ``application/*+json``); anything else — ``text/plain``, the
  type a cross-site form can send without a CORS preflight — gets 415. A request without
  a body (``/api/logout``, ``DELETE``) may omit the type.
- **Body size**: a declared ``Content-Length`` over the limit gets 413 before anything is
  read; a body without one (``Transfer-Encoding: chunked``) is counted as it arrives and,
  once over the limit, the application sees the client as gone, its answer is dropped and
  the client gets 413 with ``Connection: close``. The rest of the body is never buffered:
  at most :data:`LINGER_BYTES` (:data:`LINGER_S`) of it are read and dropped so that the
  client can read the answer before the connection closes.
"""

from __future__ import annotations

import asyncio
import json
import re
from collections.abc import Awaitable, Callable, Iterator, MutableMapping, Sequence
from dataclasses import dataclass
from typing import Any

from fastapi import params
from fastapi.routing import APIRoute
from starlette.datastructures import Headers
from starlette.responses import JSONResponse
from starlette.routing import BaseRoute, compile_path

from sage_robot.web.auth import origin_allowed

Scope = MutableMapping[str, Any]
Message = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[Message]]
Send = Callable[[Message], Awaitable[None]]
ASGIApp = Callable[[Scope, Receive, Send], Awaitable[None]]

STATE_CHANGING = frozenset({"POST", "PUT", "PATCH", "DELETE"})
JSON = "application/json"
MULTIPART = "multipart/form-data"
URLENCODED = "application/x-www-form-urlencoded"
LINGER_S = 2.0  # after a 413, the rest of the body is read and dropped this long at most (s)
LINGER_BYTES = 8 * 1024 * 1024  # ...and this much at most


def media_type(content_type: str | None) -> str:
    """``text/plain; charset=utf-8`` -> ``text/plain``."""
    return (content_type or "").partition(";")[0].strip().lower()


def expected_types(route: BaseRoute | None) -> tuple[str, ...]:
    """The body types a route reads: its File/Form parameters say multipart, else JSON."""
    if isinstance(route, APIRoute) and route.body_field is not None:
        info = route.body_field.field_info
        if isinstance(info, params.File):
            return (MULTIPART,)
        if isinstance(info, params.Form):
            return (MULTIPART, URLENCODED)
    return (JSON,)


def api_routes(routes: Sequence[BaseRoute]) -> Iterator[tuple[str, APIRoute]]:
    """Every endpoint with its full path, through included routers."""
    try:
        from fastapi.routing import iter_route_contexts  # FastAPI that keeps included routers whole
    except ImportError:
        for route in routes:
            if isinstance(route, APIRoute):
                yield route.path, route
        return
    for context in iter_route_contexts(routes):
        original = context.original_route
        if isinstance(original, APIRoute):
            yield context.path or original.path, original


@dataclass(frozen=True)
class BodyTypes:
    """Which endpoints read something other than JSON (path regex, methods, types)."""

    special: tuple[tuple[re.Pattern[str], frozenset[str], tuple[str, ...]], ...]

    @classmethod
    def of(cls, routes: Sequence[BaseRoute]) -> BodyTypes:
        found = []
        for path, route in api_routes(routes):
            types = expected_types(route)
            if types != (JSON,):
                found.append((compile_path(path)[0], frozenset(route.methods or ()), types))
        return cls(tuple(found))

    def expected(self, method: str, path: str) -> tuple[str, ...]:
        for regex, methods, types in self.special:
            if method in methods and regex.match(path):
                return types
        return (JSON,)


def type_accepted(given: str, expected: tuple[str, ...]) -> bool:
    if given in expected:
        return True
    return JSON in expected and given.startswith("application/") and given.endswith("+json")


class RequestGuard:
    """ASGI middleware: see the module's docstring.

    ``routes`` gives the application's routes (to learn what each endpoint reads),
    ``allowed_origins`` the extra origins, ``body_limit(path)`` the byte limit of a path.
    """

    def __init__(
        self,
        app: ASGIApp,
        *,
        routes: Callable[[], Sequence[BaseRoute]],
        allowed_origins: Callable[[], tuple[str, ...]],
        body_limit: Callable[[str], int],
    ) -> None:
        self.app = app
        self.routes = routes
        self._types: BodyTypes | None = None  # built on the first request, when every router is in
        self.allowed_origins = allowed_origins
        self.body_limit = body_limit

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = Headers(scope=scope)
        refusal = self._refusal(scope, headers) if scope["method"] in STATE_CHANGING else None
        if refusal is not None:
            await refusal(scope, receive, send)
            return
        limit = self.body_limit(scope["path"])
        length = headers.get("content-length", "")
        if length.isdigit() and int(length) > limit:
            waiting = headers.get("expect", "").lower() == "100-continue"  # sends nothing unless asked
            await answer_too_large(limit, receive, send, drain=not waiting)
            return
        await _limited(self.app, scope, receive, send, limit)

    def _refusal(self, scope: Scope, headers: Headers) -> JSONResponse | None:
        origin = headers.get("origin")
        if not origin_allowed(origin, headers.get("host"), self.allowed_origins()):
            return JSONResponse(
                {"error": f"refused: origin {origin} is not this server's; "
                          "list it in web.allowed_origins to allow it"},
                status_code=403,
            )  # fmt: skip
        given = media_type(headers.get("content-type"))
        has_body = headers.get("content-length", "0") not in ("", "0") or "transfer-encoding" in headers
        if not given and not has_body:
            return None
        if self._types is None:
            self._types = BodyTypes.of(self.routes())
        expected = self._types.expected(scope["method"], scope["path"])
        if not type_accepted(given, expected):
            return JSONResponse(
                {"error": f"unsupported Content-Type {given or '(none)'}: expected {' or '.join(expected)}"},
                status_code=415,
            )
        return None


async def _limited(app: ASGIApp, scope: Scope, receive: Receive, send: Send, limit: int) -> None:
    """Run ``app`` with a receive channel that stops at ``limit`` body bytes (then 413)."""
    received = 0
    over = False
    body_done = False
    started = False

    async def counted_receive() -> Message:
        nonlocal received, over, body_done
        if over:
            return {"type": "http.disconnect"}
        message = await receive()
        if message["type"] == "http.request":
            received += len(message.get("body", b""))
            if received > limit:
                over = True  # the app sees a client that went away; nothing more is read for it
                body_done = not message.get("more_body", False)
                return {"type": "http.disconnect"}
        return message

    async def guarded_send(message: Message) -> None:
        nonlocal started
        if over and not started:
            return  # the app's answer to a cut-off body is replaced by the 413
        if message["type"] == "http.response.start":
            started = True
        await send(message)

    try:
        await app(scope, counted_receive, guarded_send)
    except Exception:
        if not over:
            raise
    if over and not started:
        await answer_too_large(limit, receive, send, drain=not body_done)


async def answer_too_large(limit: int, receive: Receive, send: Send, drain: bool) -> None:
    """413 with ``Connection: close``. The answer is written first; then, unless the body is
    known to be over, up to :data:`LINGER_BYTES` more of it are read and dropped (for at most
    :data:`LINGER_S`) before the connection closes. Closing with unread bytes makes the kernel
    send a reset that can destroy the answer before a client that uploads first, reads later
    (most HTTP libraries, browsers) has seen it."""
    body = json.dumps({"error": f"request body over {limit} bytes"}).encode()
    headers = [
        (b"content-type", b"application/json"),
        (b"content-length", str(len(body)).encode()),
        (b"connection", b"close"),
    ]
    await send({"type": "http.response.start", "status": 413, "headers": headers})
    await send({"type": "http.response.body", "body": body, "more_body": True})
    if drain:
        await _drop_rest(receive)
    await send({"type": "http.response.body", "body": b"", "more_body": False})


async def _drop_rest(receive: Receive) -> None:
    loop = asyncio.get_running_loop()
    deadline = loop.time() + LINGER_S
    dropped = 0
    while dropped < LINGER_BYTES:
        try:
            message = await asyncio.wait_for(receive(), max(0.0, deadline - loop.time()))
        except asyncio.TimeoutError:
            return
        if message["type"] != "http.request":
            return
        dropped += len(message.get("body", b""))
        if not message.get("more_body", False):
            return
