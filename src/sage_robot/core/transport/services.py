"""Bus services between processes over Zenoh queries.

A process offers each of its services as a queryable on ``sage/<robot>/service/<name>`` (the
name without its leading slash). A call from another process is a Zenoh ``get`` whose payload
is the request's frame (:mod:`.wire`); the reply is the response's frame, or an error
``{"error": "ServiceError" | "ServiceTimeout" | "ServiceUnavailable", "message": ...}`` that
the caller raises as that :mod:`~sage_robot.core.errors` class. The handler runs on the
offering bus's loop; the caller waits on its own loop, bounded by the call's timeout (wall
time, also in the simulator). Each offered service also has a liveliness token
``sage/<robot>/alive/service/<zid>/<name>``, so ``bus.has_service`` knows the services of the
other processes (:class:`Directory`; Zenoh drops a dead process's tokens). Actions:
:mod:`.actions`.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import re
import threading
from collections.abc import Awaitable, Callable
from concurrent.futures import Future
from typing import Any

import zenoh

from sage_robot.core.errors import ServiceError, ServiceTimeout, ServiceUnavailable
from sage_robot.core.transport import wire
from sage_robot.core.transport.keys import PREFIX

SERVICE_NAME = re.compile(r"^/?[A-Za-z0-9_]+(/[A-Za-z0-9_]+)*$")
UNBOUNDED_CALL_S = 300.0  # a call made with timeout=None still ends (every wait is bounded)
LATE_S = 0.05  # a query that ends this close to its timeout without a reply timed out
ERRORS: dict[str, type[ServiceError]] = {
    cls.__name__: cls for cls in (ServiceError, ServiceTimeout, ServiceUnavailable)
}

_log = logging.getLogger("sage.bus.zenoh")

Call = Callable[[Any], Awaitable[Any]]


def service_key(robot: str, name: str) -> str | None:
    """The key of a service, or None for a name Zenoh cannot carry."""
    return f"{PREFIX}/{robot}/service/{name.lstrip('/')}" if SERVICE_NAME.match(name) else None


class Directory:
    """Which other processes offer which services (or actions): their liveliness tokens
    ``sage/<robot>/alive/<kind>/<zid>/<name>``, followed from the session's start (with history)."""

    def __init__(self, session: Any, robot: str, zid: str, kind: str) -> None:
        self.session, self.zid = session, zid
        self.head = f"{PREFIX}/{robot}/alive/{kind}/"
        self._servers: dict[str, list[str]] = {}  # name → zids offering it, oldest first
        self._lock = threading.Lock()
        self._sub = session.liveliness().declare_subscriber(self.head + "**", self._on_token, history=True)

    def token(self, name: str) -> Any:
        """This process offers ``name`` (undeclare the token when it stops)."""
        return self.session.liveliness().declare_token(f"{self.head}{self.zid}/{name.lstrip('/')}")

    def _on_token(self, sample: Any) -> None:  # Zenoh's thread
        zid, _, name = str(sample.key_expr)[len(self.head) :].partition("/")
        if zid == self.zid or not name:
            return
        with self._lock:
            zids = self._servers.setdefault(name, [])
            if zid in zids:
                zids.remove(zid)
            if sample.kind == zenoh.SampleKind.PUT:
                zids.append(zid)

    def server(self, name: str) -> str | None:
        """The zid of another process that offers ``name`` (the newest), or None."""
        with self._lock:
            zids = self._servers.get(name.lstrip("/"))
            return zids[-1] if zids else None

    def alive(self, name: str, zid: str) -> bool:
        with self._lock:
            return zid in self._servers.get(name.lstrip("/"), [])

    def close(self) -> None:
        with contextlib.suppress(zenoh.ZError):
            self._sub.undeclare()


class ZenohServices:
    """The services a :class:`~sage_robot.core.transport.zenoh_bus.ZenohTransport` offers
    and calls."""

    def __init__(self, session: Any, robot: str) -> None:
        self.session, self.robot = session, robot
        self.directory = Directory(session, robot, str(session.zid()), "service")
        self._offered: dict[str, tuple[Any, Any]] = {}
        self.served = 0
        self.called = 0

    # ------------------------------------------------------------ offering
    def offer(self, name: str, call: Call) -> None:
        key = service_key(self.robot, name)
        try:
            loop = asyncio.get_running_loop()
        except RuntimeError:
            loop = None
        if key is None or loop is None:
            why = "its name" if key is None else "no running loop"
            _log.warning("service %r stays in this process (%s)", name, why)
            return

        def on_query(query: Any) -> None:  # Zenoh's thread
            self._serve(loop, key, call, query)

        queryable = self.session.declare_queryable(key, on_query, allowed_origin=zenoh.Locality.REMOTE)
        self._offered[name] = (queryable, self.directory.token(name))

    def withdraw(self, name: str) -> None:
        for decl in self._offered.pop(name, ()):
            with contextlib.suppress(zenoh.ZError):
                decl.undeclare()

    def has(self, name: str) -> bool:
        """Whether another process offers the service ``name`` now."""
        return service_key(self.robot, name) is not None and self.directory.server(name) is not None

    def close(self) -> None:
        for name in list(self._offered):
            self.withdraw(name)
        self.directory.close()

    def _serve(self, loop: asyncio.AbstractEventLoop, key: str, call: Call, query: Any) -> None:
        try:
            if query.payload is None:
                raise wire.WireError("no request")
            request = wire.decode(query.payload.to_bytes())
            future = asyncio.run_coroutine_threadsafe(_awaited(call, request), loop)
        except (wire.WireError, RuntimeError) as exc:  # RuntimeError: the loop closed
            _reply_error(query, ServiceError(f"bad request: {exc}"))
            return
        self.served += 1
        future.add_done_callback(lambda f: _answer(query, key, f))

    # ------------------------------------------------------------ calling
    async def call(self, name: str, request: Any, timeout: float | None) -> Any:
        key = service_key(self.robot, name)
        if key is None:
            raise ServiceUnavailable(f"no node offers the service {name}")
        limit = UNBOUNDED_CALL_S if timeout is None else timeout
        loop = asyncio.get_running_loop()
        done: asyncio.Future[Any] = loop.create_future()
        started = loop.time()

        def settle(ok: bytes | None, err: bytes | None) -> None:  # on the loop
            if done.done():
                return
            if ok is not None:
                try:
                    done.set_result(wire.decode(ok))
                except wire.WireError as exc:
                    done.set_exception(ServiceError(f"service {name}: bad reply: {exc}"))
            elif err is not None:
                late = loop.time() - started >= limit - LATE_S
                done.set_exception(_error(name, err, limit if late else None))
            elif loop.time() - started >= limit - LATE_S:
                done.set_exception(ServiceTimeout(f"service {name} did not answer within {limit:g} s"))
            else:
                done.set_exception(ServiceUnavailable(f"no node offers the service {name}"))

        def on_reply(reply: Any) -> None:  # Zenoh's thread
            ok = reply.ok.payload.to_bytes() if reply.ok is not None else None
            err = reply.err.payload.to_bytes() if reply.ok is None else None
            _call_soon(loop, settle, ok, err)

        def on_end() -> None:  # Zenoh's thread: every reply is in (or none came)
            _call_soon(loop, settle, None, None)

        self.called += 1
        self.session.get(
            key,
            zenoh.handlers.Callback(on_reply, on_end),
            payload=wire.encode(request),
            timeout=limit,
            allowed_destination=zenoh.Locality.REMOTE,
        )
        try:
            return await asyncio.wait_for(done, limit + 1.0)
        except asyncio.TimeoutError:
            raise ServiceTimeout(f"service {name} did not answer within {limit:g} s") from None


async def _awaited(call: Call, request: Any) -> Any:
    return await call(request)


def _answer(query: Any, key: str, future: Future[Any]) -> None:
    """Reply to a remote call with its result (on the serving loop's thread)."""
    try:
        exc = future.exception() if not future.cancelled() else ServiceError("cancelled")
        if exc is not None:
            _reply_error(query, exc)
            return
        try:
            frame = wire.encode(future.result())
        except TypeError as bad:
            _reply_error(query, ServiceError(f"the reply cannot leave the process: {bad}"))
            return
        query.reply(key, frame)
    finally:
        query.drop()


def _reply_error(query: Any, exc: BaseException) -> None:
    kind = type(exc).__name__ if type(exc).__name__ in ERRORS else "ServiceError"
    with contextlib.suppress(zenoh.ZError):
        query.reply_err(json.dumps({"error": kind, "message": str(exc)}))


def _error(name: str, err: bytes, late_after: float | None) -> ServiceError:
    """The exception an error reply stands for; Zenoh's own (not JSON) at the time limit is
    its query timing out."""
    try:
        body = json.loads(err)
        return ERRORS.get(body["error"], ServiceError)(str(body["message"]))
    except (ValueError, KeyError, TypeError):
        if late_after is not None:
            return ServiceTimeout(f"service {name} did not answer within {late_after:g} s")
        return ServiceError(f"service {name} failed: {err[:200]!r}")


def _call_soon(loop: asyncio.AbstractEventLoop, fn: Callable[..., None], *args: Any) -> None:
    with contextlib.suppress(RuntimeError):  # the loop closed: nobody waits any more
        loop.call_soon_threadsafe(fn, *args)
