"""The Foxglove live view's gate on real loopback sockets: loopback by default, Origin checked,
the token required where it listens on the network (and stripped before the SDK's server)."""

from __future__ import annotations

import asyncio
import json
from collections.abc import AsyncIterator
from typing import Any

import pytest
import websockets
from websockets.exceptions import InvalidStatus
from websockets.typing import Subprotocol

from sage_robot.app.recording.gate import Upgrade, foxglove_token, is_loopback_host
from sage_robot.app.recording.nodes import FoxgloveNode
from sage_robot.core.bus import Bus
from sage_robot.core.clock import SimClock
from sage_robot.core.config import load_profile
from sage_robot.core.errors import ConfigError
from sage_robot.core.msgs import Odometry, Pose2D, Twist
from sage_robot.core.node import NodeContext

PASSWORD = "fox-test-pw"
SUBPROTOCOLS = [Subprotocol("foxglove.sdk.v1"), Subprotocol("foxglove.websocket.v1")]
WAIT_S = 5.0


async def start_node(monkeypatch: pytest.MonkeyPatch, tmp_path: Any, host: str) -> FoxgloveNode:
    monkeypatch.setenv("SAGE_OPERATOR_PASSWORD", PASSWORD)
    monkeypatch.setenv("SAGE_STATE_DIR", str(tmp_path))
    clock = SimClock()
    bus = Bus(clock)
    settings = load_profile(
        None,
        {"ops": {"foxglove_host": host, "foxglove_port": 0}, "web": {"allowed_origins": ["http://kiosk.lan"]}},
    )
    node = FoxgloveNode(NodeContext(bus, clock, settings))
    await node.setup()
    bus.publish("/odom", Odometry(0.0, Pose2D(1, 2, 0), Twist()))
    return node


@pytest.fixture
async def loopback_node(monkeypatch: pytest.MonkeyPatch, tmp_path: Any) -> AsyncIterator[FoxgloveNode]:
    node = await start_node(monkeypatch, tmp_path, "127.0.0.1")
    try:
        yield node
    finally:
        await node.teardown()


@pytest.fixture
async def network_node(monkeypatch: pytest.MonkeyPatch, tmp_path: Any) -> AsyncIterator[FoxgloveNode]:
    node = await start_node(monkeypatch, tmp_path, "0.0.0.0")  # reached here through 127.0.0.1
    try:
        yield node
    finally:
        await node.teardown()


async def server_info(url: str, **kwargs: Any) -> dict[str, Any]:
    """Open the view and return the server's first JSON message (serverInfo)."""
    async with websockets.connect(url, subprotocols=SUBPROTOCOLS, open_timeout=WAIT_S, **kwargs) as ws:
        for _ in range(20):
            raw = await asyncio.wait_for(ws.recv(), WAIT_S)
            if isinstance(raw, str):
                msg: dict[str, Any] = json.loads(raw)
                if msg.get("op") == "serverInfo":
                    return msg
    raise AssertionError("no serverInfo")


async def refused(url: str, **kwargs: Any) -> tuple[int, str]:
    with pytest.raises(InvalidStatus) as err:
        async with websockets.connect(url, subprotocols=SUBPROTOCOLS, open_timeout=WAIT_S, **kwargs):
            pass
    response = err.value.response
    return response.status_code, response.body.decode() if response.body else ""


def test_foxglove_listens_on_loopback_by_default() -> None:
    assert load_profile(None).ops.foxglove_host == "127.0.0.1"
    assert is_loopback_host("127.0.0.1")
    assert is_loopback_host("::1")
    assert is_loopback_host("localhost")
    assert not is_loopback_host("0.0.0.0")
    assert not is_loopback_host("robot.lan")


async def test_loopback_view_checks_the_browser_origin(loopback_node: FoxgloveNode) -> None:
    sock = loopback_node.gate._server.sockets[0]  # type: ignore[union-attr]
    assert sock.getsockname()[0] == "127.0.0.1"
    url = f"ws://127.0.0.1:{loopback_node.port}"
    assert (await server_info(url))["name"] == "SAGE"  # no Origin: not a browser
    for origin in ("http://localhost:3000", "https://app.foxglove.dev", "http://kiosk.lan"):
        assert (await server_info(url, origin=origin))["op"] == "serverInfo", origin
    for origin in ("https://evil.example", "null", "http://127.0.0.1.evil.example"):
        status, body = await refused(url, origin=origin)
        assert status == 403, origin
        assert "ops.foxglove_origins" in body
    assert loopback_node.stats()["refused"] == 3


async def test_network_view_requires_the_token(network_node: FoxgloveNode) -> None:
    base = f"ws://127.0.0.1:{network_node.port}"
    token = foxglove_token(PASSWORD)
    status, body = await refused(base)
    assert status == 401
    assert "token is required" in body
    status, body = await refused(f"{base}/?token={'0' * len(token)}")
    assert status == 401
    assert "wrong token" in body
    status, _ = await refused(f"{base}/?token={token}", origin="https://evil.example")
    assert status == 403  # a valid token from a foreign page is still refused
    assert (await server_info(f"{base}/?token={token}"))["name"] == "SAGE"
    bearer = {"Authorization": f"Bearer {token}"}
    assert (await server_info(base, additional_headers=bearer))["name"] == "SAGE"
    assert network_node.stats()["admitted"] == 2


def test_token_is_stable_secret_dependent_and_stripped_before_the_sdk() -> None:
    token = foxglove_token(PASSWORD)
    assert token == foxglove_token(PASSWORD)
    assert token != foxglove_token(PASSWORD + "x")
    assert PASSWORD not in token
    assert len(token) == 32
    head = (
        f"GET /live?a=1&token={token}&b=2 HTTP/1.1\r\nHost: robot:8765\r\n"
        f"Authorization: Bearer {token}\r\nSec-WebSocket-Protocol: foxglove.sdk.v1\r\n\r\n"
    ).encode()
    request = Upgrade.parse(head)
    assert request.token() == token
    forwarded = request.forwarded().decode()
    assert token not in forwarded
    assert forwarded.startswith("GET /live?a=1&b=2 HTTP/1.1\r\n")
    assert "Sec-WebSocket-Protocol: foxglove.sdk.v1\r\n" in forwarded
    assert forwarded.endswith("\r\n\r\n")


async def test_a_taken_port_is_a_clear_error_and_teardown_after_it_is_clean(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Any, loopback_node: FoxgloveNode
) -> None:
    clock = SimClock()
    ops = {"foxglove_host": "127.0.0.1", "foxglove_port": loopback_node.port}
    settings = load_profile(None, {"ops": ops})
    second = FoxgloveNode(NodeContext(Bus(clock), clock, settings))
    with pytest.raises(ConfigError, match=r"cannot listen on 127\.0\.0\.1.*ops\.foxglove_port"):
        await second.setup()
    await second.teardown()  # the launcher tears a failed node down: nothing left, no error
