"""The visitor's tour on the pages: ``/api/tour`` endpoints and the ``tour`` channel of
``/ws/status``, with the real web node (uvicorn on a loopback port) and the real tour node
on one bus. Navigation is the straight-line stand-in of the brain's tour tests; its clock is
not stepped, so a leg stays under way while the pages act on it."""

from __future__ import annotations

import asyncio
import contextlib
import json
from collections.abc import AsyncIterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import pytest
from websockets.asyncio.client import connect
from websockets.typing import Origin

from sage_robot.brain.tour_runner import TourNode
from sage_robot.core import topics
from sage_robot.core.bus import Bus
from sage_robot.core.clock import SimClock
from sage_robot.core.config import load_profile
from sage_robot.core.msgs.tour import TourCommand, TourPhase, TourState
from sage_robot.core.node import Node, NodeContext
from sage_robot.core.paths import waypoints_yaml
from sage_robot.core.places import load_places
from sage_robot.web.auth import PASSWORD_ENV
from sage_robot.web.node import WebNode

from ..brain.test_tours_sim import StraightNav
from .conftest import CHROMIUM, CHROMIUM_ARGS, artifacts_dir

PASSWORD = "tour-pages-pw"
WAIT_S = 30.0  # bound on every request and receive (a loaded 2-core machine)
AXE_JS = Path(__file__).parent / ".axe" / "node_modules" / "axe-core" / "axe.min.js"  # test_pages_layout.py


@dataclass
class Pages:
    url: str
    bus: Bus
    nav: StraightNav


@pytest.fixture
async def pages(monkeypatch: pytest.MonkeyPatch) -> AsyncIterator[Pages]:
    monkeypatch.setenv(PASSWORD_ENV, PASSWORD)
    settings = load_profile(None, {"web": {"host": "127.0.0.1", "port": 0}})
    clock = SimClock()
    bus = Bus(clock)
    ctx = NodeContext(bus, clock, settings)
    places = load_places(waypoints_yaml(settings))
    dock = places.get("DOCKING_STATION").pose
    nav = StraightNav(bus, places, dock.x, dock.y).serve()
    web = WebNode(ctx)
    nodes: list[Node] = [TourNode(ctx), web]
    for node in nodes:
        await node.setup()
    try:
        yield Pages(web.url, bus, nav)
    finally:
        for node in reversed(nodes):
            await node.teardown()
            await node._close()


async def _post(client: httpx.AsyncClient, path: str) -> httpx.Response:
    return await asyncio.wait_for(client.post(path, json={}), WAIT_S)


async def _tour_message(ws: Any, phase: str) -> dict[str, Any]:
    """The next ``tour`` message in ``phase`` on /ws/status (others are skipped)."""
    while True:
        msg: dict[str, Any] = json.loads(await asyncio.wait_for(ws.recv(), WAIT_S))
        if msg.get("type") == "tour" and msg["phase"] == phase:
            return msg


async def _until_estop(ws: Any, engaged: bool) -> None:
    while True:
        msg = json.loads(await asyncio.wait_for(ws.recv(), WAIT_S))
        if msg.get("type") == "estop" and msg["engaged"] is engaged:
            return


async def test_tour_state_and_commands_on_the_pages(pages: Pages) -> None:
    ws_url = pages.url.replace("http://", "ws://") + "/ws/status"
    async with httpx.AsyncClient(base_url=pages.url, timeout=WAIT_S) as visitor, \
            httpx.AsyncClient(base_url=pages.url, timeout=WAIT_S) as op, \
            connect(ws_url, origin=Origin(pages.url), open_timeout=WAIT_S) as ws:  # fmt: skip
        idle = (await asyncio.wait_for(visitor.get("/api/tour"), WAIT_S)).json()["tour"]
        assert idle["phase"] == "idle"
        assert idle["stops"] == []
        await _tour_message(ws, "idle")
        none = await _post(visitor, "/api/tour/stop")
        assert none.status_code == 409
        assert none.json() == {"error": "no tour is running"}

        start = TourCommand("start", ("GUELLY_DELLY", "CLEAN_ROOM"))  # as the brain's start_tour does
        started = await pages.bus.call(topics.TOUR_CONTROL, start)
        assert isinstance(started, TourState)
        assert started.phase is TourPhase.DRIVING
        shown = await _tour_message(ws, "driving")
        assert shown["current"] == "GUELLY_DELLY"
        assert shown["current_title"] == "Guelly Delly café"
        assert [(s["name"], s["status"]) for s in shown["stops"]] == [("GUELLY_DELLY", "current"),
                                                                       ("CLEAN_ROOM", "ahead")]  # fmt: skip

        assert (await _post(visitor, "/api/tour/pause")).status_code == 401  # the operator's
        login = await asyncio.wait_for(op.post("/api/login", json={"password": PASSWORD}), WAIT_S)
        assert login.status_code == 200
        paused = await _post(op, "/api/tour/pause")
        assert paused.status_code == 200, paused.text
        assert paused.json()["tour"]["phase"] == "paused"
        assert (await _tour_message(ws, "paused"))["reason"] == "paused"
        again = await _post(op, "/api/tour/pause")
        assert again.status_code == 409
        assert again.json() == {"error": "the tour is already paused"}
        unknown = await _post(op, "/api/tour/teleport")
        assert unknown.status_code == 404
        assert "commands: pause, resume, skip, stop" in unknown.json()["error"]

        cookie = f"sage_session={login.cookies['sage_session']}"
        async with connect(pages.url.replace("http://", "ws://") + "/ws/teleop", origin=Origin(pages.url),
                           additional_headers={"Cookie": cookie}, open_timeout=WAIT_S) as teleop:  # fmt: skip
            await teleop.send(json.dumps({"type": "estop", "engaged": True}))
            await _until_estop(teleop, engaged=True)
            refused = await _post(op, "/api/tour/resume")
            assert refused.status_code == 409
            assert refused.json() == {"error": "e-stop is engaged: release it first"}
            await teleop.send(json.dumps({"type": "estop", "engaged": False}))
            await _until_estop(teleop, engaged=False)

        skipped = await _post(op, "/api/tour/skip")
        assert skipped.status_code == 200
        tour = skipped.json()["tour"]
        assert tour["current"] == "CLEAN_ROOM"
        assert [s["status"] for s in tour["stops"]] == ["skipped", "current"]
        assert (await _post(op, "/api/tour/resume")).json() == {"error": "the tour is not paused"}

        ended = await _post(visitor, "/api/tour/stop")  # a visitor at the face ends it
        assert ended.status_code == 200
        assert ended.json()["tour"]["phase"] == "stopped"
        assert (await _tour_message(ws, "stopped"))["reason"] == "stopped on request"
        assert pages.bus.actions.active(topics.NAVIGATE_TO) is None  # its leg was cancelled
        assert pages.nav.goals == ["GUELLY_DELLY", "CLEAN_ROOM"]


def _need_chromium() -> None:
    if not Path(CHROMIUM).exists():
        pytest.fail(f"{CHROMIUM} is missing: apt-get install chromium (see scripts/apt-packages.txt)")


def _axe_installed() -> bool:
    return AXE_JS.exists()


async def _axe_blocking(page: Any, selector: str) -> list[str]:
    """Serious or critical axe-core violations inside ``selector`` (none checked without axe)."""
    if not _axe_installed():
        return []
    await page.add_script_tag(path=str(AXE_JS))
    result = await page.evaluate(f"axe.run({selector!r}, {{resultTypes: ['violations']}})")
    return [f"{v['id']}: {v['help']}" for v in result["violations"] if v["impact"] in ("serious", "critical")]


async def _start(pages: Pages) -> None:
    start = TourCommand("start", ("GUELLY_DELLY", "CLEAN_ROOM"))
    assert isinstance(await pages.bus.call(topics.TOUR_CONTROL, start), TourState)


def _phase(pages: Pages) -> str:
    state = pages.bus.latest(topics.TOUR_STATE)
    return state.phase.value if isinstance(state, TourState) else ""


@pytest.mark.browser
async def test_the_tour_on_the_face_and_on_teleop(pages: Pages) -> None:
    """In Chromium: the face's tour card (stops, current one) and its End tour; teleop's
    Tour panel pausing and resuming."""
    _need_chromium()
    from playwright.async_api import async_playwright

    wait_ms = WAIT_S * 1000
    shots = artifacts_dir()
    await _start(pages)
    async with async_playwright() as pw:
        browser = await pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS, headless=True)
        try:
            page = await browser.new_page(viewport={"width": 1280, "height": 800})
            errors: list[str] = []
            page.on("pageerror", lambda e: errors.append(str(e)))
            await page.goto(f"{pages.url}/face")
            await page.wait_for_selector("#tour:not([hidden])", timeout=wait_ms)
            assert await page.text_content("#tour-phase") == "On our way to Guelly Delly café"
            items = await page.locator("#tour-stops li").all_text_contents()
            assert items == ["▶ Guelly Delly café", "Clean Room"]
            await page.screenshot(path=str(shots / "face-tour.png"))
            assert await _axe_blocking(page, "#tour") == []
            await page.click("#tour-stop")  # a visitor ends it
            await page.wait_for_function(
                "document.getElementById('tour-phase').textContent === 'Tour ended'", timeout=wait_ms
            )
            assert _phase(pages) == "stopped"

            await _start(pages)
            await page.goto(f"{pages.url}/teleop")
            await page.fill("#password", PASSWORD)
            await page.click("button[type=submit]")
            await page.wait_for_url(f"{pages.url}/teleop", timeout=wait_ms)
            await page.wait_for_selector("#tour:not([hidden])", timeout=wait_ms)
            assert await page.is_hidden("#tour-resume")
            await page.click("#tour-pause")
            await page.wait_for_selector("#tour-resume:not([hidden])", timeout=wait_ms)
            shown = await page.text_content("#tour-phase") or ""
            assert shown.startswith("Paused — next: Guelly Delly café")
            assert _phase(pages) == "paused"
            await page.click("#tour-resume")
            await page.wait_for_selector("#tour-pause:not([hidden])", timeout=wait_ms)
            assert _phase(pages) == "driving"
            await page.screenshot(path=str(shots / "teleop-tour.png"), full_page=True)
            assert await _axe_blocking(page, "#tour") == []
            assert not errors, errors
        finally:
            with contextlib.suppress(Exception):
                await browser.close()
