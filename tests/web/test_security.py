"""The web server's door on real loopback sockets: Origin and Content-Type of state-changing
requests, body limits on streamed (chunked) bodies, forwarded addresses, numbers past float range.

The login rate-limit test uses up this module's login budget: it runs last.
"""

from __future__ import annotations

import contextlib
import json
import select
import socket
import threading
import time
from collections.abc import Iterator
from typing import Any
from urllib.parse import urlsplit

import httpx
import pytest
import uvicorn

from sage_robot.web.app import body_limit
from sage_robot.web.common import LOGIN_BURST
from sage_robot.web.node import proxy_options

from ..support.waits import wait_until
from .wsclient import recv_json, teleop_ws

WAIT_S = 10.0
FOREIGN = "http://evil.example"
CHUNK = 64 * 1024
CHUNKED_TOTAL_BYTES = 200 * 1024 * 1024  # what the client offers to send
KERNEL_SLACK_BYTES = 32 * 1024 * 1024  # loopback socket buffers the client fills before the cut shows


def own_origin(robot: Any) -> str:
    parts = urlsplit(robot.url)
    return f"{parts.scheme}://{parts.netloc}"


# ------------------------------------------------------------------ Origin
def test_foreign_origin_cannot_change_state_even_when_logged_in(
    robot: Any, client: httpx.Client, cookie: str
) -> None:
    goals_before = len(robot.goals)
    for path, body in (("/api/goal", {"place": "LOBBY"}), ("/api/cancel", {}), ("/api/logout", {})):
        resp = client.post(path, json=body, headers={"Origin": FOREIGN, "Cookie": cookie})
        assert resp.status_code == 403, path
        assert "web.allowed_origins" in resp.json()["error"]
    assert len(robot.goals) == goals_before
    whoami = client.get("/api/whoami", headers={"Cookie": cookie}).json()
    assert whoami == {"operator": True}  # the forged logout did nothing


def test_own_origin_and_no_origin_are_admitted(robot: Any, client: httpx.Client, cookie: str) -> None:
    pose = {"x": 0.0, "y": 0.0, "theta": 0.0}
    headers = {"Cookie": cookie, "Origin": own_origin(robot)}
    assert client.post("/api/initial_pose", json=pose, headers=headers).status_code == 200
    assert client.post("/api/initial_pose", json=pose, headers={"Cookie": cookie}).status_code == 200
    reads = client.get("/api/health", headers={"Origin": FOREIGN})  # reading is not guarded
    assert reads.status_code == 200


# ------------------------------------------------------------------ Content-Type
def test_simple_request_content_types_are_refused_with_415(client: httpx.Client, cookie: str) -> None:
    body = json.dumps({"place": "LOBBY"})
    for kind in ("text/plain", "application/x-www-form-urlencoded", "text/plain; charset=utf-8"):
        resp = client.post("/api/goal", content=body, headers={"Content-Type": kind, "Cookie": cookie})
        assert resp.status_code == 415, kind
        assert "expected application/json" in resp.json()["error"]
    no_type = client.post("/api/goal", content=body, headers={"Cookie": cookie})
    assert no_type.status_code == 415
    upload_as_json = client.post("/api/talk/audio", json={"audio": "x"})
    assert upload_as_json.status_code == 415
    assert "multipart/form-data" in upload_as_json.json()["error"]


def test_expected_types_and_bodyless_requests_pass(client: httpx.Client, cookie: str) -> None:
    files = {"audio": ("a.webm", b"not really webm", "audio/webm")}
    upload = client.post("/api/talk/audio", files=files)
    assert upload.status_code not in (403, 413, 415)  # reached the endpoint (voice may be absent)
    suffixed = client.post(
        "/api/initial_pose",
        content=json.dumps({"x": 1.0, "y": 1.0}),
        headers={"Content-Type": "application/merge-patch+json", "Cookie": cookie},
    )
    assert suffixed.status_code == 200
    bodyless = client.request("DELETE", "/api/kb/documents/987654", headers={"Cookie": cookie})
    assert bodyless.status_code in (404, 503)  # no document / KB not running: not refused at the door


# ------------------------------------------------------------------ body limits
def chunked_post(url: str, path: str, total: int, headers: dict[str, str] | None = None) -> tuple[int, bytes]:
    """POST ``total`` bytes as ``Transfer-Encoding: chunked`` until the server answers or cuts
    the connection; (bytes sent, the response received)."""
    host, port = urlsplit(url).hostname, urlsplit(url).port
    assert host
    assert port
    extra = "".join(f"{k}: {v}\r\n" for k, v in (headers or {}).items())
    head = (
        f"POST {path} HTTP/1.1\r\nHost: {host}:{port}\r\nContent-Type: application/json\r\n"
        f"Transfer-Encoding: chunked\r\n{extra}\r\n"
    )
    chunk = f"{CHUNK:x}\r\n".encode() + b" " * CHUNK + b"\r\n"
    sent, response = 0, b""
    deadline = time.monotonic() + 60.0
    with socket.create_connection((host, port), timeout=WAIT_S) as sock:
        sock.sendall(head.encode())
        with contextlib.suppress(BrokenPipeError, ConnectionResetError):
            while sent < total and time.monotonic() < deadline:
                readable, _, _ = select.select([sock], [], [], 0)
                if readable:
                    break
                sock.sendall(chunk)
                sent += CHUNK
            if sent >= total:
                sock.sendall(b"0\r\n\r\n")
        sock.settimeout(WAIT_S)
        with contextlib.suppress(ConnectionResetError, TimeoutError):
            while data := sock.recv(65536):  # until the server closes the connection
                response += data
    return sent, response


def read_response(sock: socket.socket) -> bytes:
    """One whole response with a Content-Length (each wait bounded by the socket's timeout)."""
    data = b""
    while True:
        head, sep, body = data.partition(b"\r\n\r\n")
        if sep:
            length = int(head.lower().split(b"content-length: ")[1].split(b"\r\n")[0])
            if len(body) >= length:
                return data
        more = sock.recv(65536)
        assert more, f"the connection closed before a whole response: {data[:200]!r}"
        data += more


def test_chunked_body_over_the_limit_is_cut_off_while_streaming(robot: Any, cookie: str) -> None:
    limit = body_limit("/api/initial_pose")  # an endpoint that reads its body (logged in)
    sent, response = chunked_post(robot.url, "/api/initial_pose", CHUNKED_TOTAL_BYTES, {"Cookie": cookie})
    assert response.startswith(b"HTTP/1.1 413"), response[:200]
    assert b"request body over" in response
    assert sent < limit + KERNEL_SLACK_BYTES, f"the client pushed {sent} bytes before the cut"
    assert sent < CHUNKED_TOTAL_BYTES


def test_declared_length_over_the_limit_is_refused_before_reading(robot: Any) -> None:
    limit = body_limit("/api/login")
    parts = urlsplit(robot.url)
    head = (
        f"POST /api/login HTTP/1.1\r\nHost: {parts.netloc}\r\nContent-Type: application/json\r\n"
        f"Content-Length: {limit + 1}\r\n\r\n"
    )
    with socket.create_connection((parts.hostname, parts.port), timeout=WAIT_S) as sock:
        sock.sendall(head.encode())  # not one byte of the body: the answer must not wait for it
        response = read_response(sock)
    assert response.startswith(b"HTTP/1.1 413"), response[:200]
    assert f"over {limit} bytes".encode() in response


def test_chunked_body_under_the_limit_still_works(robot: Any, cookie: str) -> None:
    body = json.dumps({"x": 0.5, "y": 0.25, "theta": 0.0}).encode()

    def parts() -> Iterator[bytes]:
        yield body[:5]
        yield body[5:]

    resp = httpx.post(
        f"{robot.url}/api/initial_pose",
        content=parts(),
        headers={"Content-Type": "application/json", "Cookie": cookie},
        timeout=WAIT_S,
    )
    assert resp.request.headers.get("transfer-encoding") == "chunked"
    assert resp.status_code == 200


# ------------------------------------------------------------------ numbers past float range
@pytest.mark.parametrize(
    ("path", "raw", "field"),
    [
        ("/api/goal", '{"x": 1' + "0" * 400 + ', "y": 0, "theta": 0}', "x"),
        ("/api/goal", '{"x": 1, "y": 1e400, "theta": 0}', "y"),
        ("/api/initial_pose", '{"x": 0, "y": 0, "theta": NaN}', "theta"),
        ("/api/admin/places", '{"name": "HUGE", "x": 0, "y": -Infinity}', "y"),
        ("/api/slam/save", '{"name": "m", "extra": [1, 2, 1e999]}', "extra[2]"),
    ],
)
def test_numbers_past_float_range_get_422_naming_the_field(
    client: httpx.Client, cookie: str, path: str, raw: str, field: str
) -> None:
    resp = client.post(path, content=raw, headers={"Content-Type": "application/json", "Cookie": cookie})
    assert resp.status_code == 422, resp.text
    assert resp.json()["error"].startswith(f"{field}: expected a finite number")


def test_socket_answers_bad_numbers_and_stays_open(robot: Any, cookie: str) -> None:
    with teleop_ws(robot, cookie) as ws:
        bad = (
            '{"type": "control", "x": 1' + "0" * 400 + ', "z": 0}',
            '{"type": "control", "x": 1e400, "z": 0}',
            '{"type": "ping", "t": ' + "9" * 5000 + "}",  # past Python's int-parsing limit
        )
        for text in bad:
            ws.send(text)
            reply = recv_json(ws, "error")
            assert "number" in reply["error"] or "JSON" in reply["error"], reply
        ws.send(json.dumps({"type": "ping", "t": 7}))
        assert recv_json(ws, "pong")["t"] == 7


# ------------------------------------------------------------------ forwarded addresses
class EchoClient:
    """A real uvicorn server whose app answers with the client address it believes."""

    def __init__(self, trusted: tuple[str, ...]) -> None:
        async def app(scope: Any, receive: Any, send: Any) -> None:
            if scope["type"] != "http":
                return
            host = (scope.get("client") or ("?", 0))[0]
            await send({"type": "http.response.start", "status": 200, "headers": []})
            await send({"type": "http.response.body", "body": host.encode()})

        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.port = self.sock.getsockname()[1]
        config = uvicorn.Config(app, log_level="warning", lifespan="off", **proxy_options(trusted))
        self.server = uvicorn.Server(config)
        self.thread = threading.Thread(target=lambda: self.server.run(sockets=[self.sock]), daemon=True)

    def __enter__(self) -> EchoClient:
        self.thread.start()
        wait_until(lambda: self.server.started, "uvicorn to start", WAIT_S)
        return self

    def __exit__(self, *exc: object) -> None:
        self.server.should_exit = True
        self.thread.join(WAIT_S)
        self.sock.close()

    def seen_as(self, forwarded_for: str) -> str:
        url = f"http://127.0.0.1:{self.port}/"
        return httpx.get(url, headers={"X-Forwarded-For": forwarded_for}, timeout=WAIT_S).text


def test_forwarded_for_is_believed_only_from_configured_proxies() -> None:
    with EchoClient(trusted=()) as untrusted:
        assert untrusted.seen_as("203.0.113.7") == "127.0.0.1"
    with EchoClient(trusted=("127.0.0.1",)) as trusted:
        assert trusted.seen_as("203.0.113.7") == "203.0.113.7"


def test_forwarded_for_from_loopback_does_not_dodge_the_login_limit(robot: Any, cookie: str) -> None:
    attempts = 11
    statuses = [
        httpx.post(
            f"{robot.url}/api/login",
            json={"password": "wrong"},
            headers={"X-Forwarded-For": f"198.51.100.{i}"},
            timeout=WAIT_S,
        ).status_code
        for i in range(attempts)
    ]
    assert set(statuses) <= {401, 429}, statuses
    assert statuses.count(429) >= attempts - LOGIN_BURST - 1, statuses  # 1: a token refilled meanwhile
    assert statuses[-1] == 429
