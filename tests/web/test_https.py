"""HTTPS on the robot (issue #21): the certificate, the plain-http redirect, the talk QR code on
the face, and /talk telling a visitor before any press whether voice can work.

Real servers: the web node (with a stand-in brain) listening on every address, reached at this
machine's non-loopback address, as a phone on the robot's network reaches it; real Chromium at
phone size. Screenshots land in $SAGE_ARTIFACTS/web.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import ssl
import stat
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest

from sage_robot.app.launcher import Launcher, NodeSpec
from sage_robot.brain.base import Utterance
from sage_robot.core import topics
from sage_robot.core.actions import GoalContext
from sage_robot.core.bus import Bus
from sage_robot.core.clock import WallClock
from sage_robot.core.config import load_profile
from sage_robot.core.errors import ConfigError
from sage_robot.core.msgs import Text
from sage_robot.core.node import NodeContext
from sage_robot.web import tls
from sage_robot.web.node import WEB_URL, WebNode
from sage_robot.web.talk import qr_svg

from ..support.waits import until
from .conftest import PASSWORD, artifacts_dir, operator_env

START_TIMEOUT_S = 20.0
WAIT_MS = 30_000
PHONE = {"width": 390, "height": 844}


def lan_ip() -> str:
    addrs = tls.lan_addresses()
    if not addrs:
        pytest.skip("this machine has no non-loopback IPv4 address to reach the robot at")
    return addrs[0]


# ---------------------------------------------------------------- settings and the certificate
def test_tls_setting_auto_follows_the_listening_address() -> None:
    web = load_profile(None).web
    assert web.tls == "auto"
    assert web.host == "0.0.0.0"
    assert tls.tls_enabled(web)  # the robot as shipped: phones reach it, so HTTPS
    assert not tls.tls_enabled(load_profile(None, {"web": {"host": "127.0.0.1"}}).web)
    assert not tls.tls_enabled(load_profile(None, {"web": {"tls": False}}).web)  # YAML `off`
    assert tls.tls_enabled(load_profile(None, {"web": {"tls": True, "host": "127.0.0.1"}}).web)
    with pytest.raises(ConfigError):
        load_profile(None, {"web": {"tls": "sometimes"}})


def test_certificate_is_made_once_with_the_machine_addresses_and_reused(tmp_path: Path) -> None:
    ip = lan_ip()
    web = load_profile(None).web
    first = tls.ensure_certificate(web, tmp_path)
    assert first.made_here
    assert first.cert == tmp_path / "tls" / "cert.pem"
    pem, mtime = first.cert.read_bytes(), first.cert.stat().st_mtime_ns
    assert stat.S_IMODE(first.key.stat().st_mode) == 0o600
    dns, ips = tls.cert_names(pem)
    assert ip in ips
    assert "127.0.0.1" in ips
    assert "localhost" in dns
    again = tls.ensure_certificate(web, tmp_path)
    assert again == first
    assert again.cert.read_bytes() == pem
    assert again.cert.stat().st_mtime_ns == mtime


def test_certificate_is_made_anew_for_a_new_address(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    ip = lan_ip()
    web = load_profile(None).web
    monkeypatch.setattr(tls, "lan_addresses", list)  # made while the robot had no network
    old = tls.ensure_certificate(web, tmp_path).cert.read_bytes()
    assert ip not in tls.cert_names(old)[1]
    monkeypatch.undo()  # now it has one: a phone must find it in the certificate
    new = tls.ensure_certificate(web, tmp_path).cert.read_bytes()
    assert new != old
    assert ip in tls.cert_names(new)[1]


def test_operator_certificate_is_used_as_it_is(tmp_path: Path) -> None:
    own = tls.ensure_certificate(load_profile(None).web, tmp_path / "own")
    web = load_profile(None, {"web": {"tls_cert": str(own.cert), "tls_key": str(own.key)}}).web
    pair = tls.ensure_certificate(web, tmp_path / "state")
    assert (pair.cert, pair.key, pair.made_here) == (own.cert, own.key, False)
    assert not (tmp_path / "state" / "tls").exists()
    with pytest.raises(ConfigError, match="go together"):
        tls.ensure_certificate(load_profile(None, {"web": {"tls_cert": str(own.cert)}}).web, tmp_path)
    missing = load_profile(None, {"web": {"tls_cert": str(tmp_path / "no.pem"), "tls_key": str(own.key)}})
    with pytest.raises(ConfigError, match="not found"):
        tls.ensure_certificate(missing.web, tmp_path)


def test_redirect_location_keeps_path_and_query() -> None:
    app = tls.RedirectToHttps(8000, "10.0.0.5")
    assert app.location("robot.local:8080", "/talk", "a=1&b=2") == "https://robot.local:8000/talk?a=1&b=2"
    assert app.location(None, "/", "") == "https://10.0.0.5:8000/"
    assert tls.RedirectToHttps(443, "h").location("[fe80::1]:80", "/x", "") == "https://[fe80::1]/x"


# ---------------------------------------------------------------- real servers
class WebServer:
    """The web node alone (plus a stand-in brain) on its own loop thread."""

    def __init__(self, web: dict[str, Any], state: Path) -> None:
        self.settings = load_profile(None, {"web": web})
        self.state = state  # its SAGE_STATE_DIR (the certificate is in tls/)
        self.loop = asyncio.new_event_loop()
        self.questions: list[str] = []
        self.thread = threading.Thread(target=self.loop.run_forever, name="web-only", daemon=True)

    def start(self) -> WebServer:
        self.thread.start()
        asyncio.run_coroutine_threadsafe(self._start(), self.loop).result(START_TIMEOUT_S)
        return self

    async def _start(self) -> None:
        clock = WallClock()
        self.ctx = NodeContext(Bus(clock), clock, self.settings)
        self.launcher = Launcher(self.ctx, [NodeSpec("web", WebNode)])
        await self.launcher.start()
        self.ctx.bus.actions.serve(topics.CONVERSE, self._converse)
        self.url = await until(lambda: self.ctx.resources.get(WEB_URL), "the web server's address",
                               START_TIMEOUT_S)
        self.node: Any = self.launcher.nodes["web"]

    async def _converse(self, goal: Text | Utterance, ctx: GoalContext) -> Text:
        heard = goal.data if isinstance(goal, Text) else goal.text
        self.questions.append(heard)
        return Text(f"You asked about {heard.rstrip('?')}. It is on the first floor.")

    def stop(self) -> None:
        with contextlib.suppress(Exception):
            asyncio.run_coroutine_threadsafe(self.launcher.stop(), self.loop).result(10)
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(10)


@contextlib.contextmanager
def web_server(tmp: Path, web: dict[str, Any]) -> Iterator[WebServer]:
    with operator_env(tmp / "state"):
        server = WebServer({"host": "0.0.0.0", "port": 0, **web}, tmp / "state").start()
        try:
            yield server
        finally:
            server.stop()


@pytest.fixture(scope="module")
def https_robot(tmp_path_factory: pytest.TempPathFactory) -> Iterator[WebServer]:
    lan_ip()
    with web_server(tmp_path_factory.mktemp("https"), {"tls": "on", "http_port": 0}) as server:
        yield server


@pytest.fixture(scope="module")
def http_robot(tmp_path_factory: pytest.TempPathFactory) -> Iterator[WebServer]:
    lan_ip()
    with web_server(tmp_path_factory.mktemp("plain"), {"tls": "off"}) as server:
        yield server


def trusting(server: WebServer) -> ssl.SSLContext:
    """Trusts the robot's self-signed certificate and checks the host name against it."""
    ctx = ssl.create_default_context(cafile=str(server.state / "tls" / "cert.pem"))
    ctx.verify_flags |= ssl.VERIFY_X509_PARTIAL_CHAIN
    return ctx


def lan_url(server: WebServer, path: str = "") -> str:
    return f"https://{lan_ip()}:{server.node.port}{path}"


def test_https_serves_talk_at_the_lan_address_with_a_valid_certificate(https_robot: WebServer) -> None:
    assert https_robot.url.startswith("https://")
    made = (https_robot.state / "tls" / "cert.pem").read_bytes()
    with httpx.Client(verify=trusting(https_robot), timeout=30) as c:  # host name checked: the SAN holds
        resp = c.get(lan_url(https_robot, "/talk"))
        assert resp.status_code == 200
        assert "Talk to SAGE" in resp.text
    kept = tls.ensure_certificate(https_robot.settings.web, https_robot.state)
    assert kept.cert.read_bytes() == made


def test_plain_http_port_redirects_keeping_path_and_query(https_robot: WebServer) -> None:
    port = https_robot.node.http_port
    assert port is not None
    assert port != https_robot.node.port
    plain = f"http://{lan_ip()}:{port}/talk?lang=en&x=%20y"
    resp = httpx.get(plain, follow_redirects=False)
    assert resp.status_code == 308
    assert resp.headers["location"] == lan_url(https_robot, "/talk?lang=en&x=%20y")
    with httpx.Client(verify=trusting(https_robot), follow_redirects=True) as c:
        final = c.get(plain)
    assert final.status_code == 200
    assert str(final.url).startswith("https://")
    assert "Talk to SAGE" in final.text


def test_session_cookie_is_secure_on_https(https_robot: WebServer) -> None:
    with httpx.Client(verify=trusting(https_robot)) as c:
        resp = c.post(lan_url(https_robot, "/api/login"), json={"password": PASSWORD})
    assert resp.status_code == 200
    cookie = resp.headers["set-cookie"]
    assert "sage_session=" in cookie
    assert "Secure" in cookie
    assert "HttpOnly" in cookie


def test_sage_status_speaks_https_to_the_robot(https_robot: WebServer) -> None:
    url = f"https://127.0.0.1:{https_robot.node.port}"
    env = {**os.environ, "SAGE_STATE_DIR": str(https_robot.state)}  # it trusts the certificate there
    proc = subprocess.run([sys.executable, "-m", "sage_robot.cli.main", "status", "--url", url],
                          capture_output=True, text=True, timeout=60, env=env)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert "web" in proc.stdout
    assert "running" in proc.stdout


def test_talk_qr_svg_is_the_https_talk_url_at_the_lan_address(https_robot: WebServer) -> None:
    want = lan_url(https_robot, "/talk")
    with httpx.Client(verify=False) as c:  # from the robot itself (loopback): still the LAN address
        info = c.get(f"https://127.0.0.1:{https_robot.node.port}/api/talk_url").json()
        svg = c.get(f"https://127.0.0.1:{https_robot.node.port}/api/talk_qr.svg")
    assert info == {"url": want, "secure": True}
    assert svg.status_code == 200
    assert svg.headers["content-type"].startswith("image/svg+xml")
    assert svg.headers["x-talk-url"] == want
    assert svg.text == qr_svg(want)  # the very symbol segno makes of that text
    assert svg.text.lstrip().startswith("<svg")


def decode_qr(png: bytes) -> str:
    import cv2

    img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_GRAYSCALE)
    assert img is not None
    text, _, _ = cv2.QRCodeDetector().detectAndDecode(img)
    return str(text)


@pytest.mark.browser
def test_face_shows_a_scannable_qr_code_of_talk(https_robot: WebServer, browser: Any) -> None:
    ctx = browser.new_context(viewport={"width": 1280, "height": 800}, ignore_https_errors=True)
    try:
        page = ctx.new_page()
        page.goto(lan_url(https_robot, "/face"))
        page.wait_for_selector("#talk-qr:not([hidden])", timeout=WAIT_MS)
        assert page.inner_text("#talk-qr").startswith("Scan to talk to me")
        page.screenshot(path=str(artifacts_dir() / "face-qr-1280x800.png"))
        assert decode_qr(page.locator("#talk-qr-img").screenshot()) == lan_url(https_robot, "/talk")
    finally:
        ctx.close()


@pytest.mark.browser
def test_phone_on_https_lan_address_can_hold_to_talk(https_robot: WebServer, browser: Any) -> None:
    ctx = browser.new_context(viewport=PHONE, ignore_https_errors=True, has_touch=True, is_mobile=True)
    uploads: list[bytes] = []

    def fake_stt(route: Any) -> None:  # the page's recording reaches the server's audio route
        uploads.append(route.request.post_data_buffer or b"")
        route.fulfill(json={"transcript": "where is the cafe", "reply": "On the first floor."})

    try:
        page = ctx.new_page()
        page.route("**/api/talk/audio", fake_stt)
        page.goto(lan_url(https_robot, "/talk"))
        assert page.evaluate("window.isSecureContext") is True
        page.wait_for_function("document.body.dataset.mic === 'available'", timeout=WAIT_MS)
        assert page.is_visible("#ptt")
        assert page.is_enabled("#ptt")
        assert page.is_hidden("#mic-note")
        page.screenshot(path=str(artifacts_dir() / "talk-https-390x844.png"))
        box = page.locator("#ptt").bounding_box()
        assert box is not None
        page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
        page.mouse.down()  # hold to talk: the fake microphone records
        page.wait_for_selector("#ptt.recording", timeout=WAIT_MS)
        page.wait_for_timeout(600)
        page.mouse.up()
        page.wait_for_function("Number(document.body.dataset.replies || 0) >= 1", timeout=WAIT_MS)
        assert uploads
        assert b"audio/webm" in uploads[0]
        assert "On the first floor." in page.inner_text("#conversation")
    finally:
        ctx.close()


@pytest.mark.browser
def test_phone_on_plain_http_lan_address_is_told_before_pressing(http_robot: WebServer, browser: Any) -> None:
    assert http_robot.url.startswith("http://")
    ctx = browser.new_context(viewport=PHONE, has_touch=True, is_mobile=True)
    try:
        page = ctx.new_page()
        page.goto(f"http://{lan_ip()}:{http_robot.node.port}/talk")
        assert page.evaluate("window.isSecureContext") is False
        page.wait_for_selector("#mic-note:not([hidden])", timeout=WAIT_MS)  # no press happened
        note = page.inner_text("#mic-note")
        assert "Voice needs" in note
        assert "type instead" in note
        assert page.is_hidden("#ptt")
        assert page.evaluate("document.body.dataset.mic") == "unavailable"
        page.screenshot(path=str(artifacts_dir() / "talk-http-390x844.png"))
        page.fill("#question", "where is the cafe?")  # typing stays
        page.click("#ask button[type=submit]")
        page.wait_for_function("Number(document.body.dataset.replies || 0) >= 1", timeout=WAIT_MS)
        assert "first floor" in page.inner_text("#conversation")
        assert http_robot.questions == ["where is the cafe?"]
    finally:
        ctx.close()
