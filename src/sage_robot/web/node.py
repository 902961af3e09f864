"""WebNode: the one web server (pages, REST, WebSockets), on the bus's asyncio loop.

uvicorn's ``Server.serve()`` runs as a task of the node, so handlers publish on the bus
directly with no thread hop. The listening socket is bound in ``setup`` (a busy port
fails the start with a message that names it); ``web.port`` 0 picks a free port, which
is then in :attr:`WebNode.port` and ``ctx.resources[WEB_URL]``. With HTTPS (``web.tls``,
:mod:`sage_robot.web.tls`) a second small server on ``web.http_port`` redirects plain http
to it (its port in :attr:`WebNode.http_port`).
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import logging
import socket
from collections.abc import Iterator
from typing import Any

import uvicorn

from sage_robot.core import topics
from sage_robot.core.errors import ConfigError
from sage_robot.core.log import RECENT
from sage_robot.core.node import Node
from sage_robot.core.resources import ResourceKey
from sage_robot.web import tls

WS_MAX_MESSAGE_BYTES = 64 * 1024  # larger WebSocket messages close the socket (1009)
SHUTDOWN_GRACE_S = 1  # open connections get this long to finish on stop (s)
WEB_URL = ResourceKey("web_url", str)  # the server's base URL, once it listens


class WebNode(Node):
    name = "web"

    async def setup(self) -> None:
        from sage_robot.web.app import create_app
        from sage_robot.web.auth import RateLimiter, Sessions, operator_password
        from sage_robot.web.common import TALK_BURST, WebState
        from sage_robot.web.hub import Hub
        from sage_robot.web.teleop import Teleop

        _keep_recent_logs()
        web = self.settings.web
        self.bus.declare(topics.HEALTH)  # latched: the launcher's or supervisor's report (/api/health)
        self.hub = Hub(self)
        self.hub.start()
        self.teleop = Teleop(self, self.hub)
        self.teleop.start()
        self.sessions = Sessions(operator_password(self.settings))
        self.state = WebState(
            self,
            self.hub,
            self.teleop,
            self.sessions,
            talk_limiter=RateLimiter(web.talk_per_min, TALK_BURST),
        )
        self.app = create_app(self.state)
        self.tls = tls.tls_enabled(web)
        cert = await asyncio.to_thread(tls.ensure_certificate, web) if self.tls else None
        self.sock = _bind(web.host, web.port)
        self.port = int(self.sock.getsockname()[1])
        shown = "127.0.0.1" if web.host in ("0.0.0.0", "::") else web.host
        self.url = f"{'https' if self.tls else 'http'}://{tls.url_host(shown)}:{self.port}"
        self.ctx.resources[WEB_URL] = self.url
        config = uvicorn.Config(
            self.app,
            log_level="warning",
            access_log=False,
            lifespan="off",
            ws_max_size=WS_MAX_MESSAGE_BYTES,
            timeout_graceful_shutdown=SHUTDOWN_GRACE_S,
            **proxy_options(web.trusted_proxies),
            ssl_certfile=str(cert.cert) if cert else None,
            ssl_keyfile=str(cert.key) if cert else None,
        )
        self.server = _QuietServer(config)
        self._serve_task = self.spawn(self.server.serve(sockets=[self.sock]), "web.server")
        self.http_port: int | None = None
        if self.tls and web.http_port is not None:
            self._start_redirect(web.host, 0 if web.port == 0 else web.http_port)
        self.log.info("web server listening", url=self.url, http_redirect_port=self.http_port)

    def _start_redirect(self, host: str, port: int) -> None:
        """Plain http on ``port`` → 308 to HTTPS. A busy port is a warning: the pages still work."""
        try:
            self.redirect_sock = _bind(host, port)
        except ConfigError as exc:
            self.log.warning("no plain-http redirect", error=str(exc).replace("web.port", "web.http_port"))
            return
        self.http_port = int(self.redirect_sock.getsockname()[1])
        app = tls.RedirectToHttps(self.port, tls.public_host(self.settings.web))
        config = uvicorn.Config(app, log_level="warning", access_log=False, lifespan="off",
                                timeout_graceful_shutdown=SHUTDOWN_GRACE_S, proxy_headers=False)
        self.redirect_server = _QuietServer(config)
        self._redirect_task = self.spawn(self.redirect_server.serve(sockets=[self.redirect_sock]),
                                         "web.http_redirect")

    async def teardown(self) -> None:
        await _stop_server(getattr(self, "redirect_server", None), getattr(self, "_redirect_task", None))
        await _stop_server(getattr(self, "server", None), getattr(self, "_serve_task", None))
        hub = getattr(self, "hub", None)
        if hub is not None:
            hub.stop()
        teleop = getattr(self, "teleop", None)
        if teleop is not None and teleop.command != (0.0, 0.0):
            teleop._publish(0.0, 0.0)
        for sock in (getattr(self, "sock", None), getattr(self, "redirect_sock", None)):
            if sock is not None:
                with contextlib.suppress(OSError):
                    sock.close()

    def stats(self) -> dict[str, Any]:
        hub, teleop = getattr(self, "hub", None), getattr(self, "teleop", None)
        return {
            "clients": len(hub.listeners) if hub else 0,
            "frames_in": hub.counts["frames_in"] if hub else 0,
            "camera_viewers": hub.camera_viewers if hub else 0,
            **(teleop.counts if teleop else {}),
            "estop": bool(hub.estop) if hub else False,
        }


async def _stop_server(server: uvicorn.Server | None, task: asyncio.Task[Any] | None) -> None:
    if server is not None:
        server.should_exit = True  # closes sockets (1012) and open connections
    if task is not None and not task.done():
        with contextlib.suppress(asyncio.TimeoutError, asyncio.CancelledError, Exception):
            await asyncio.wait_for(asyncio.shield(task), SHUTDOWN_GRACE_S + 1.0)
    for listener in getattr(server, "servers", []):  # a serve task that died (crash, cancel)
        listener.close()  # left its listener in the loop; a new socket could reuse its fd


def proxy_options(trusted_proxies: tuple[str, ...]) -> dict[str, Any]:
    """uvicorn settings that believe ``X-Forwarded-For``/``-Proto`` only from ``trusted_proxies``.

    uvicorn's own default believes them from 127.0.0.1, which lets anything on the robot (or
    a local proxy that passes the header on) pick its client address, e.g. to dodge the
    per-address login limit. With no trusted proxies the headers are ignored altogether.
    """
    if not trusted_proxies:
        return {"proxy_headers": False, "forwarded_allow_ips": []}
    return {"proxy_headers": True, "forwarded_allow_ips": list(trusted_proxies)}


def _bind(host: str, port: int) -> socket.socket:
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
    except OSError as exc:
        sock.close()
        if exc.errno == errno.EADDRINUSE:
            raise ConfigError(
                f"web.port {port} on {host} is in use by another program; "
                "stop it or set web.port in the profile"
            ) from None
        raise ConfigError(f"web: cannot listen on {host}:{port}: {exc.strerror}") from None
    sock.listen(128)
    sock.setblocking(False)
    return sock


def _keep_recent_logs() -> None:
    """The admin page shows recent logs: make sure the ring buffer is attached."""
    root = logging.getLogger("sage")
    if RECENT not in root.handlers:
        root.addHandler(RECENT)
    if root.level == logging.NOTSET or root.level > logging.INFO:
        root.setLevel(logging.INFO)


class _QuietServer(uvicorn.Server):
    """uvicorn without its signal handlers: the launcher owns SIGINT/SIGTERM."""

    @contextlib.contextmanager
    def capture_signals(self) -> Iterator[None]:
        yield
