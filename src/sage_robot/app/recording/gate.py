"""The Foxglove live view's door: a small TCP gate in front of the Foxglove SDK's server.

The SDK's WebSocket server (``foxglove.start_server``) has no login and no ``Origin``
check, so it listens on an ephemeral loopback port only and this gate listens on
``ops.foxglove_host:ops.foxglove_port``. The gate reads the client's HTTP upgrade request
(at most :data:`MAX_HEAD_BYTES`, within :data:`HANDSHAKE_TIMEOUT_S`), checks it, then
relays bytes both ways unchanged, so every Foxglove subprotocol works:

- **Origin** (browsers always send it): a page on a loopback host (``localhost``,
  ``127.0.0.0/8``, ``[::1]``), the gate's own ``Host``, ``web.allowed_origins`` or
  ``ops.foxglove_origins``; anything else gets HTTP 403. No ``Origin``: not a browser.
- **Token**: where the gate listens on an address that is not loopback, the request
  must carry the Foxglove token as ``?token=...`` in the URL (what the Foxglove app can
  send: it keeps the URL's query) or ``Authorization: Bearer ...``; else HTTP 401. The
  token is an HMAC of the operator password (:func:`foxglove_token`; print it with
  ``python -m sage_robot.app.recording.gate [PROFILE.yaml]``); it is stripped before the
  request is passed on.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import hmac
import ipaddress
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any
from urllib.parse import parse_qsl, urlencode, urlsplit, urlunsplit

MAX_HEAD_BYTES = 16 * 1024  # an upgrade request's line and headers, at most
HANDSHAKE_TIMEOUT_S = 5.0  # a client has this long to send its upgrade request (s)
RELAY_CHUNK_BYTES = 64 * 1024
MAX_CLIENTS = 16  # Foxglove viewers at once; more are refused (503)
TOKEN_CONTEXT = b"sage foxglove token v1"
TOKEN_HEX_CHARS = 32  # 128 bits


def foxglove_token(password: str) -> str:
    """The Foxglove token: HMAC-SHA256 of a fixed context under the operator password.

    Stable across restarts (a saved Foxglove connection keeps working), changes with the
    password, and does not reveal it.
    """
    digest = hmac.new(password.encode("utf-8"), TOKEN_CONTEXT, hashlib.sha256).hexdigest()
    return digest[:TOKEN_HEX_CHARS]


def is_loopback_host(host: str | None) -> bool:
    """``localhost``, 127.0.0.0/8 or ::1 (brackets allowed); False for 0.0.0.0 and names."""
    if not host:
        return False
    host = host.strip("[]").lower()
    if host == "localhost" or host.endswith(".localhost"):
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def origin_allowed(origin: str | None, host: str | None, allowed: tuple[str, ...]) -> bool:
    """A browser's ``Origin`` for the Foxglove view: loopback page, own host, or listed."""
    if origin is None:
        return True
    if origin in allowed:
        return True
    parts = urlsplit(origin)
    if parts.scheme not in ("http", "https") or not parts.netloc:
        return False
    if is_loopback_host(parts.hostname):
        return True
    return host is not None and parts.netloc.lower() == host.lower()


@dataclass(frozen=True)
class Refusal:
    status: int
    reason: str
    message: str

    def response(self) -> bytes:
        body = (self.message + "\n").encode("utf-8")
        head = (
            f"HTTP/1.1 {self.status} {self.reason}\r\n"
            "Content-Type: text/plain; charset=utf-8\r\n"
            f"Content-Length: {len(body)}\r\n"
            "Connection: close\r\n\r\n"
        )
        return head.encode("latin-1") + body


@dataclass(frozen=True)
class Upgrade:
    """A parsed upgrade request: its target and headers (names lower-case, first value)."""

    method: str
    target: str
    version: str
    headers: dict[str, str]
    lines: tuple[str, ...]  # the header lines as sent

    @classmethod
    def parse(cls, head: bytes) -> Upgrade:
        text = head.decode("latin-1")
        request_line, *header_lines = [line for line in text.split("\r\n") if line]
        parts = request_line.split(" ")
        if len(parts) != 3:
            raise ValueError("malformed request line")
        headers: dict[str, str] = {}
        for line in header_lines:
            name, sep, value = line.partition(":")
            if not sep:
                raise ValueError("malformed header line")
            headers.setdefault(name.strip().lower(), value.strip())
        return cls(parts[0], parts[1], parts[2], headers, tuple(header_lines))

    def token(self) -> str | None:
        for key, value in parse_qsl(urlsplit(self.target).query, keep_blank_values=True):
            if key == "token":
                return value
        scheme, _, value = self.headers.get("authorization", "").partition(" ")
        return value.strip() if scheme.lower() == "bearer" and value.strip() else None

    def forwarded(self) -> bytes:
        """The request as passed on: without the token (query) and the Authorization header."""
        url = urlsplit(self.target)
        query = urlencode([(k, v) for k, v in parse_qsl(url.query, keep_blank_values=True) if k != "token"])
        target = urlunsplit(("", "", url.path or "/", query, ""))
        kept = [ln for ln in self.lines if ln.partition(":")[0].strip().lower() != "authorization"]
        return "\r\n".join([f"{self.method} {target} {self.version}", *kept, "", ""]).encode("latin-1")


def check(request: Upgrade, token: str | None, origins: tuple[str, ...]) -> Refusal | None:
    """Why this upgrade request is refused, or None when it may pass."""
    origin = request.headers.get("origin")
    if not origin_allowed(origin, request.headers.get("host"), origins):
        return Refusal(
            403,
            "Forbidden",
            f"SAGE Foxglove: origin {origin} is not allowed; add it to ops.foxglove_origins "
            "(or web.allowed_origins) in the profile",
        )
    if token is not None:
        given = request.token()
        if given is None:
            return Refusal(
                401, "Unauthorized", "SAGE Foxglove: a token is required: connect to ws://HOST:PORT/?token=..."
            )
        if not hmac.compare_digest(given.encode("utf-8"), token.encode("utf-8")):
            return Refusal(401, "Unauthorized", "SAGE Foxglove: wrong token")
    return None


class FoxgloveGate:
    """Listens on the public address; admits checked clients to ``127.0.0.1:upstream_port``."""

    def __init__(
        self,
        upstream_port: int,
        token: str | None,
        origins: tuple[str, ...],
        log: Any,
        on_viewers: Callable[[int], None] | None = None,
    ) -> None:
        self.upstream_port = upstream_port
        self.token = token
        self.origins = origins
        self.log = log
        self.on_viewers = on_viewers  # called with the number of viewers whenever it changes
        self.viewers = 0
        self.counts = {"admitted": 0, "refused": 0}
        self._tasks: set[asyncio.Task[None]] = set()
        self._server: asyncio.Server | None = None

    async def start(self, host: str, port: int) -> int:
        """Listen; the bound port (``port`` 0 = any free one). OSError when it cannot."""
        self._server = await asyncio.start_server(self._accept, host, port, limit=MAX_HEAD_BYTES)
        return int(self._server.sockets[0].getsockname()[1])

    async def stop(self) -> None:
        if self._server is not None:
            self._server.close()
        for task in list(self._tasks):
            task.cancel()
        if self._tasks:
            await asyncio.gather(*self._tasks, return_exceptions=True)
        if self._server is not None:
            with contextlib.suppress(Exception):
                await asyncio.wait_for(self._server.wait_closed(), HANDSHAKE_TIMEOUT_S)

    async def _accept(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None
        self._tasks.add(task)
        try:
            await self._handle(reader, writer)
        except (ConnectionError, asyncio.IncompleteReadError, asyncio.LimitOverrunError, OSError):
            pass
        finally:
            self._tasks.discard(task)
            writer.close()
            with contextlib.suppress(Exception):
                await writer.wait_closed()

    async def _handle(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        peer = writer.get_extra_info("peername")
        try:
            head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), HANDSHAKE_TIMEOUT_S)
            request = Upgrade.parse(head)
        except (asyncio.TimeoutError, asyncio.LimitOverrunError, ValueError):
            bad = Refusal(400, "Bad Request", "SAGE Foxglove: bad upgrade request")
            await self._refuse(writer, bad, peer)
            return
        refusal = check(request, self.token, self.origins)
        if refusal is None and len(self._tasks) > MAX_CLIENTS:
            refusal = Refusal(503, "Service Unavailable", f"SAGE Foxglove: {MAX_CLIENTS} viewers already")
        if refusal is not None:
            await self._refuse(writer, refusal, peer, request.headers.get("origin"))
            return
        up_reader, up_writer = await asyncio.open_connection("127.0.0.1", self.upstream_port)
        self.counts["admitted"] += 1
        self._viewers(+1)
        try:
            up_writer.write(request.forwarded())
            await _relay_both(reader, writer, up_reader, up_writer)
        finally:
            self._viewers(-1)
            up_writer.close()
            with contextlib.suppress(Exception):
                await up_writer.wait_closed()

    def _viewers(self, change: int) -> None:
        self.viewers += change
        if self.on_viewers is not None:
            self.on_viewers(self.viewers)

    async def _refuse(
        self, writer: asyncio.StreamWriter, refusal: Refusal, peer: Any, origin: str | None = None
    ) -> None:
        self.counts["refused"] += 1
        self.log.warning("Foxglove connection refused", client=str(peer), origin=origin, why=refusal.message)
        writer.write(refusal.response())
        with contextlib.suppress(Exception):
            await asyncio.wait_for(writer.drain(), HANDSHAKE_TIMEOUT_S)


async def _pipe(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
    while data := await reader.read(RELAY_CHUNK_BYTES):
        writer.write(data)
        await writer.drain()


async def _relay_both(
    a_reader: asyncio.StreamReader,
    a_writer: asyncio.StreamWriter,
    b_reader: asyncio.StreamReader,
    b_writer: asyncio.StreamWriter,
) -> None:
    """Copy both directions until either side closes; then both stop."""
    tasks = [
        asyncio.ensure_future(_pipe(a_reader, b_writer)),
        asyncio.ensure_future(_pipe(b_reader, a_writer)),
    ]
    try:
        await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
    finally:
        for t in tasks:
            t.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)


def main(argv: list[str] | None = None) -> int:
    """``python -m sage_robot.app.recording.gate [PROFILE.yaml]``: print the Foxglove token."""
    import sys

    from sage_robot.core.config import load_profile
    from sage_robot.web.auth import operator_password

    args = sys.argv[1:] if argv is None else argv
    print(foxglove_token(operator_password(load_profile(args[0] if args else None))))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
