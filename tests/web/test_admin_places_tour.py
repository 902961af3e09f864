"""Saved SLAM maps on the operator's pages: list them, make one the tour map, in a real browser.

The real web node (uvicorn on a free loopback port) and the real slam node share a bus on the
simulated clock; ray-cast scans of a drawn corridor loop (``tests/slam/synth.py``) are fed
to the slam node, then:

- over HTTP: ``GET /api/slam/maps`` and ``POST /api/slam/tour-map`` with their refusals
  (401 without login, 422 for a bad name or a broken map, 404 for a missing one), the
  written profile loading as the tour map, a second choice keeping the places added since;
- in Chromium: the teleop page's "Save map" (shown while SLAM runs) and "Use as tour map",
  then the admin page's saved-maps list.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import pytest

from sage_robot.core.bus import Bus
from sage_robot.core.clock import SimClock
from sage_robot.core.config import load_profile
from sage_robot.core.msgs import Pose2D
from sage_robot.core.node import Node, NodeContext
from sage_robot.core.paths import package_data
from sage_robot.core.places import Place, Places, load_places, write_places
from sage_robot.nav.mapdata import load_for
from sage_robot.nav.slam.messages import SlamProgress
from sage_robot.nav.slam.node import OUT_DIR_RESOURCE, SLAM_PROGRESS, SlamNode
from sage_robot.nav.slam.tour import START_PLACE
from sage_robot.web.auth import PASSWORD_ENV
from sage_robot.web.node import WebNode

from ..slam.synth import corridor_loop, loop_path, publish_step, simulate
from .conftest import CHROMIUM, CHROMIUM_ARGS, artifacts_dir

PASSWORD = "tour-map-pw"
WAIT_S = 30.0  # bound on every wait (a loaded 2-core machine)
SCANS = 12  # scans fed to the slam node: a few metres of the corridor
AXE_JS = Path(__file__).parent / ".axe" / "node_modules" / "axe-core" / "axe.min.js"  # test_pages_layout.py
BLOCKING = ("serious", "critical")  # axe impacts that fail the test


@dataclass
class Mapping:
    url: str
    maps: Path
    bus: Bus


@pytest.fixture
async def mapping(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> AsyncIterator[Mapping]:
    """The web and slam nodes on one bus, SCANS scans mapped."""
    monkeypatch.setenv(PASSWORD_ENV, PASSWORD)
    settings = load_profile(
        None,
        {
            "robot": {"lidar": {"x_m": 0.0, "y_m": 0.0, "yaw_rad": 0.0}},
            "web": {"host": "127.0.0.1", "port": 0},
        },
    )
    clock = SimClock()
    bus = Bus(clock)
    ctx = NodeContext(bus, clock, settings)
    ctx.resources[OUT_DIR_RESOURCE] = str(tmp_path / "maps")
    web = WebNode(ctx)
    nodes: list[Node] = [web, SlamNode(ctx)]
    for node in nodes:
        await node.setup()
    try:
        progress = bus.subscribe(SLAM_PROGRESS, SlamProgress, maxsize=100)
        drive = simulate(corridor_loop(), loop_path(step_m=0.3)[:SCANS], yaw_drift=0.0)
        for k in range(SCANS):
            await publish_step(bus, clock, drive, k)
            await asyncio.wait_for(progress.get(), WAIT_S)
        yield Mapping(web.url, tmp_path / "maps", bus)
    finally:
        for node in reversed(nodes):
            await node.teardown()
            await node._close()


async def _request(client: httpx.AsyncClient, method: str, path: str, body: Any = None) -> httpx.Response:
    return await asyncio.wait_for(client.request(method, path, json=body), WAIT_S)


async def test_saved_maps_are_listed_and_one_becomes_the_tour_map(mapping: Mapping) -> None:
    async with httpx.AsyncClient(base_url=mapping.url, timeout=WAIT_S) as op:
        assert (await _request(op, "GET", "/api/slam/maps")).status_code == 401
        assert (await _request(op, "POST", "/api/slam/tour-map", {"name": "x"})).status_code == 401
        assert (await _request(op, "POST", "/api/login", {"password": PASSWORD})).status_code == 200
        listed = (await _request(op, "GET", "/api/slam/maps")).json()
        assert listed == {"directory": str(mapping.maps), "maps": []}
        assert (await _request(op, "POST", "/api/slam/save", {"name": "loop"})).status_code == 200
        listed = (await _request(op, "GET", "/api/slam/maps")).json()
        assert [(m["name"], m["tour_profile"]) for m in listed["maps"]] == [("loop", False)]

        bad = await _request(op, "POST", "/api/slam/tour-map", {"name": "../etc"})
        assert bad.status_code == 422
        assert "use letters" in bad.json()["error"]
        missing = await _request(op, "POST", "/api/slam/tour-map", {"name": "nowhere"})
        assert missing.status_code == 404
        assert missing.json()["error"] == f"no saved map 'nowhere' in {mapping.maps}"

        chosen = await _request(op, "POST", "/api/slam/tour-map", {"name": "loop"})
        assert chosen.status_code == 200, chosen.text
        tour = chosen.json()
        assert tour["profile"] == str(mapping.maps / "loop.profile.yaml")
        assert tour["command"] == f"sage sim --profile {tour['profile']}"
        settings = load_profile(tour["profile"])  # the tour profile loads, and names the new map
        assert settings.nav.map == str(mapping.maps / "loop.yaml")
        assert settings.nav.initial_place == START_PLACE
        assert Path(settings.sim.world_map) == package_data("maps", "campus", "map.yaml").resolve()
        data = load_for(settings)  # what the map server loads at the next start
        start = data.places.get(START_PLACE)
        assert start is not None
        first = loop_path(step_m=0.3)[0]  # where mapping began (the synthetic drive's first pose)
        assert abs(start.pose.x - first[0]) < 0.05
        assert abs(start.pose.y - first[1]) < 0.05

        # Places added since are kept when the map is chosen again.
        places = load_places(settings.nav.waypoints)
        extra = Place("HALL", Pose2D(start.pose.x + 1.0, start.pose.y, 0.0), "the hall", ("hall",))
        write_places(Places([*places, extra], places.source), settings.nav.waypoints)
        again = await _request(op, "POST", "/api/slam/tour-map", {"name": "loop"})
        assert again.json()["places"] == 2

        # A map without its trajectory: one clear line.
        (mapping.maps / "loop.trajectory.txt").unlink()
        (mapping.maps / "loop.waypoints.yaml").unlink()
        broken = await _request(op, "POST", "/api/slam/tour-map", {"name": "loop"})
        assert broken.status_code == 422
        assert "loop.trajectory.txt: cannot read the trajectory" in broken.json()["error"]
        assert "\n" not in broken.json()["error"]


async def _axe_blocking(page: Any, selector: str) -> list[str]:
    """Serious or critical axe-core violations inside ``selector`` (none checked without axe)."""
    if not _axe_installed():
        return []
    await page.add_script_tag(path=str(AXE_JS))
    result = await page.evaluate(f"axe.run({selector!r}, {{resultTypes: ['violations']}})")
    return [f"{v['id']}: {v['help']}" for v in result["violations"] if v["impact"] in BLOCKING]


def _axe_installed() -> bool:
    return AXE_JS.exists()


def _need_chromium() -> None:
    if not Path(CHROMIUM).exists():
        pytest.fail(f"{CHROMIUM} is missing: apt-get install chromium (see scripts/apt-packages.txt)")


@pytest.mark.browser
async def test_teleop_saves_the_map_and_admin_makes_it_the_tour_map(mapping: Mapping) -> None:
    _need_chromium()
    from playwright.async_api import async_playwright

    wait_ms = WAIT_S * 1000
    shots = artifacts_dir()  # screenshots: $SAGE_ARTIFACTS/web
    async with async_playwright() as pw:
        browser = await pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS, headless=True)
        try:
            page = await browser.new_page()
            errors: list[str] = []
            page.on("pageerror", lambda e: errors.append(str(e)))
            await page.goto(f"{mapping.url}/teleop")
            await page.fill("#password", PASSWORD)
            await page.click("button[type=submit]")
            await page.wait_for_url(f"{mapping.url}/teleop", timeout=wait_ms)
            # The mapping panel shows while SLAM runs, with the progress.
            await page.wait_for_selector("#slam-panel:not([hidden])", timeout=wait_ms)
            await page.wait_for_function(
                "document.getElementById('slam-progress').textContent.includes('12 scans')", timeout=wait_ms
            )
            await page.fill("#slam-name", "bad/name")
            await page.click("#slam-save-btn")
            assert "use letters" in (await page.text_content("#slam-msg") or "")
            await page.fill("#slam-name", "first_floor")
            await page.click("#slam-save-btn")
            await page.wait_for_selector("#slam-tour:not([hidden])", timeout=wait_ms)
            assert "saved " in (await page.text_content("#slam-msg") or "")
            assert (mapping.maps / "first_floor.yaml").exists()
            await page.click("#slam-tour")
            await page.wait_for_function(
                "document.getElementById('slam-msg').textContent.includes('is the tour map')", timeout=wait_ms
            )
            assert (mapping.maps / "first_floor.profile.yaml").exists()
            await page.screenshot(path=str(shots / "teleop-slam.png"), full_page=True)
            assert await _axe_blocking(page, "#slam-panel") == []

            await page.goto(f"{mapping.url}/admin")
            button = await page.wait_for_selector("button[data-map=first_floor]", timeout=wait_ms)
            assert button is not None
            assert "has a tour profile" in (await page.text_content("#saved-maps") or "")
            await button.click()
            await page.wait_for_function(
                "document.getElementById('tourmap-msg').textContent.includes('sage sim --profile')",
                timeout=wait_ms,
            )
            await page.screenshot(path=str(shots / "admin-saved-maps.png"), full_page=True)
            assert await _axe_blocking(page, "#saved-maps") == []
            assert not errors, errors
        finally:
            with contextlib.suppress(Exception):
                await browser.close()
