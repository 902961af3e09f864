"""The owners' workflow end to end on the simulator (issue #23): map the building, then tour it.

1. ``sage slam``'s context (profile ``sim_slam``: world, firmware model behind a pty, serial
   bridge, web, slam) on the simulated clock; the robot is driven by /cmd_vel out of the
   docking alcove and down the corridor while the map grows on ``/map``.
2. Over real HTTP on loopback: log in, ``POST /api/slam/save``, ``GET /api/slam/maps``,
   ``POST /api/slam/tour-map`` (writes ``NAME.profile.yaml`` and ``NAME.waypoints.yaml``).
3. The tour: the written profile started with the map server, localization, navigator, web
   and brain; a place is added through the admin API (a point on the new map), then a
   visitor types "take me to …" on ``/api/talk/text`` and the robot drives there.
"""

from __future__ import annotations

import asyncio
import io
import math
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from PIL import Image
from websockets.sync.client import connect

from sage_robot.app.launcher import Launcher, NodeSpec
from sage_robot.app.registry import node_class
from sage_robot.app.runtime import make_context, run_launcher, specs_for
from sage_robot.cli.main import main
from sage_robot.cli.slam import mapping_context
from sage_robot.core import topics
from sage_robot.core.config import load_profile
from sage_robot.core.mapio import read_map
from sage_robot.core.msgs import Event, OccupancyGrid, Text, Twist
from sage_robot.core.msgs.nav import PlaceList
from sage_robot.nav.slam.engine import Slam
from sage_robot.nav.slam.node import SLAM_SAVE
from sage_robot.nav.slam.store import save_session
from sage_robot.nav.slam.tour import START_PLACE
from sage_robot.sim.node import WORLD_RESOURCE
from sage_robot.web.auth import PASSWORD_ENV
from sage_robot.web.node import WEB_URL

from ..support.waits import sim_until
from ..web.wsclient import recv_json
from .synth import corridor_loop, loop_path, simulate

PASSWORD = "workflow-pw"
HTTP_TIMEOUT_S = 60.0  # each request answers within this (a loaded 2-core machine)
WALL_LIMIT_S = 240.0  # bound on each phase (wall clock)
CMD_PERIOD_S = 0.05  # /cmd_vel is re-sent at 20 Hz (the firmware stops after 0.55 s without)
# The drive (the bundled teleop_drive scenario's first 15 s): (s from the drive's start, linear m/s,
# angular rad/s).
ROUTE = [(0.5, 0.4, 0.0), (7.25, 0.0, -0.8), (9.21, 0.6, 0.0), (16.0, 0.0, 0.0)]
DRIVE_START_S = 10.0  # simulated s: the page view before the drive has ended by then (about 2 s)
DRIVE_END_S = 17.0  # simulated s from the drive's start: stopped by then
MAP_NODES = {"sim_world", "mcu_sim", "serial_bridge", "web", "slam"}
TOUR_NODES = ["sim_world", "mcu_sim", "serial_bridge", "map_server", "localization", "navigator", "web",
              "brain"]  # fmt: skip
NEW_PLACE = {  # down the corridor the drive mapped, facing south
    "name": "ROBOT_CORNER", "x": 50.0, "y": 54.5, "theta": -math.pi / 2,
    "description": "where the robots charge", "aliases": "robot corner, the robot corner",
}  # fmt: skip
WALL_X = 51.15  # the corridor's east wall (m; mapped 51.1-51.2 at y 54.5), where a place is refused
LIST_WAIT_S = 5.0  # bound on one place-list call (simulated s)
LIST_TRIES, LIST_POLL_S = 50, 0.1  # the map server lists the new place within 5 simulated s
PAGE_POSE_TOLERANCE_M = 0.3  # the page's robot vs the true pose (SLAM error + the robot at rest)
ARRIVAL_TOLERANCE_M = 0.5  # goal tolerance + localization error on a fresh SLAM map
TOUR_SIM_LIMIT_S = 200.0  # simulated seconds the tour may take
SYNTH_SCANS = 12  # scans of the drawn corridor for the command-line test


def _common(overrides: dict[str, Any]) -> dict[str, Any]:
    return {
        "sim": {"pedestrians": 0, "camera_hz": 0, **overrides},
        "web": {"host": "127.0.0.1", "port": 0},
        "ops": {"foxglove_port": 0},
    }


def _login(client: httpx.Client) -> httpx.Client:
    resp = client.post("/api/login", json={"password": PASSWORD})
    assert resp.status_code == 200, resp.text
    return client


def _client(url: str) -> httpx.Client:
    return httpx.Client(base_url=url, timeout=HTTP_TIMEOUT_S)


def _known_cells(grid: OccupancyGrid | None) -> int:
    return 0 if grid is None else int((grid.data >= 0).sum())


async def _drive(ctx: Any) -> None:
    """Standing /cmd_vel commands along ROUTE, re-sent every CMD_PERIOD_S (simulated), from
    DRIVE_START_S or later. Time runs as fast as possible while the test's HTTP client waits, so
    the page view before the drive takes however much simulated time the machine gives it: the
    drive is timed from its own start, and on any machine but a very slow one that start is
    DRIVE_START_S, so the run is the same every time."""
    cmd = Twist()
    await ctx.clock.sleep_until(DRIVE_START_S)
    start = ctx.clock.now()
    while ctx.clock.now() - start < DRIVE_END_S:
        now = ctx.clock.now() - start
        for at, v, w in ROUTE:
            if now >= at:
                cmd = Twist(v, w)
        ctx.bus.publish(topics.CMD_VEL, cmd)
        await ctx.clock.sleep(CMD_PERIOD_S)


def _page_view(url: str) -> tuple[int, dict[str, Any]]:
    """What the teleop page shows: the known pixels of its live map (``/api/map.png``; unknown
    is the most common shade) and the robot's pose from ``/ws/live``."""
    with _client(url) as op:
        _login(op)
        resp = op.get("/api/map.png")
        assert resp.status_code == 200, resp.text
        cookie = f"sage_session={op.cookies['sage_session']}"
    img = np.asarray(Image.open(io.BytesIO(resp.content)).convert("L"))
    unknown = np.bincount(img.ravel()).argmax()
    live = url.replace("http://", "ws://") + "/ws/live"
    with connect(live, additional_headers={"Cookie": cookie}, open_timeout=HTTP_TIMEOUT_S) as ws:
        pose = recv_json(ws, "pose", HTTP_TIMEOUT_S)
    return int((img != unknown).sum()), pose


def _save_and_choose(url: str) -> dict[str, Any]:
    """What the owner does on the pages after driving: save, list, make it the tour map."""
    with _client(url) as op:
        _login(op)
        assert op.post("/api/slam/save", json={"name": "../x"}).status_code == 422
        saved = op.post("/api/slam/save", json={"name": "hall"})
        assert saved.status_code == 200, saved.text
        listed = op.get("/api/slam/maps").json()
        assert [m["name"] for m in listed["maps"]] == ["hall"]
        missing = op.post("/api/slam/tour-map", json={"name": "nowhere"})
        assert missing.status_code == 404
        assert "no saved map 'nowhere'" in missing.json()["error"]
        chosen = op.post("/api/slam/tour-map", json={"name": "hall"})
        assert chosen.status_code == 200, chosen.text
        return {"saved": saved.json(), "tour": chosen.json()}


def _add_places(url: str) -> dict[str, Any]:
    """The admin page's "add a place": one in a wall (refused), then NEW_PLACE."""
    with _client(url) as op:
        _login(op)
        wall = {**NEW_PLACE, "name": "IN_THE_WALL", "x": WALL_X}
        refused = op.post("/api/admin/places", json=wall)
        assert refused.status_code == 422, refused.text
        added = op.post("/api/admin/places", json=NEW_PLACE)
        assert added.status_code == 200, added.text
        saved = [m["name"] for m in op.get("/api/slam/maps").json()["maps"]]
        return {"refused": refused.json()["error"], "file": added.json()["file"], "saved_maps": saved}


async def _map_phase(tmp_path: Path) -> dict[str, Any]:
    settings = load_profile(None, _common({"speed": None}))
    ctx = mapping_context(settings, str(tmp_path / "maps"), "autosave")
    specs = [s for s in specs_for("sim_slam") if s.name in MAP_NODES]
    grown: list[int] = []  # known cells of /map: before and after the drive
    page: list[tuple[int, dict[str, Any]]] = []  # the page's live map and robot: before, after
    result: dict[str, Any] = {}

    async def owner(launcher: Launcher) -> None:
        try:
            await sim_until(ctx.clock, lambda: ctx.bus.latest(topics.MAP), "the first map", 10.0)
            grown.append(_known_cells(ctx.bus.latest(topics.MAP)))
            page.append(await asyncio.to_thread(_page_view, ctx.resources[WEB_URL]))
            await _drive(ctx)
            grown.append(_known_cells(ctx.bus.latest(topics.MAP)))
            page.append(await asyncio.to_thread(_page_view, ctx.resources[WEB_URL]))
            result.update(await asyncio.to_thread(_save_and_choose, ctx.resources[WEB_URL]))
        finally:
            launcher.request_stop()

    async def after_start(launcher: Launcher) -> None:
        result["task"] = asyncio.get_running_loop().create_task(owner(launcher))

    launcher = await asyncio.wait_for(run_launcher(ctx, specs, after_start=after_start), WALL_LIMIT_S)
    result.pop("task").result()  # the owner's failure, if any
    assert not [n for n, h in launcher.health.items() if h.restarts], launcher.health
    assert not ctx.bus.has_service(SLAM_SAVE)
    assert grown[1] > 2 * grown[0], grown  # the map grew while the robot drove
    assert page[1][0] > 1.5 * page[0][0], page  # and so did the teleop page's live map
    truth = ctx.resources[WORLD_RESOURCE].pose
    # The page draws the robot on the map (SLAM's map->odom), in the building's frame.
    pose = page[1][1]
    assert pose["frame"] == "map", pose
    assert math.hypot(pose["x"] - truth[0], pose["y"] - truth[1]) < PAGE_POSE_TOLERANCE_M, (pose, truth)
    assert truth[1] < NEW_PLACE["y"], truth  # it went down the corridor past the new place
    return result


async def _tour_phase(profile: str) -> dict[str, Any]:
    settings = load_profile(profile, _common({"speed": None}))
    ctx = make_context(settings, simulated=True)
    specs = [NodeSpec(n, node_class(n), False) for n in TOUR_NODES]
    arrived: list[Event] = []
    result: dict[str, Any] = {}

    async def lists_new_place() -> bool:
        reply = await ctx.bus.call(topics.PLACES, Text(""), timeout=LIST_WAIT_S)
        return isinstance(reply, PlaceList) and NEW_PLACE["name"] in [p.name for p in reply.places]

    async def visitor(launcher: Launcher) -> None:
        try:
            url = ctx.resources[WEB_URL]
            ctx.bus.subscribe(topics.EVENTS, Event, lambda e: arrived.extend([e][: e.kind == "arrived"]))
            result.update(await asyncio.to_thread(_add_places, url))
            for _ in range(LIST_TRIES):  # map_server re-reads the file on the places_changed event
                if await lists_new_place():
                    break
                await ctx.clock.sleep(LIST_POLL_S)
            else:
                raise AssertionError("the map server never listed the added place")
            talk = await asyncio.to_thread(
                httpx.post, f"{url}/api/talk/text", json={"text": "Take me to the robot corner, please"},
                timeout=HTTP_TIMEOUT_S,
            )  # fmt: skip
            assert talk.status_code == 200, talk.text
            result["reply"] = talk.json()["reply"]
            await sim_until(ctx.clock, lambda: arrived, "the arrival", TOUR_SIM_LIMIT_S, step_s=0.5)
        finally:
            launcher.request_stop()

    async def after_start(launcher: Launcher) -> None:
        result["task"] = asyncio.get_running_loop().create_task(visitor(launcher))

    launcher = await asyncio.wait_for(run_launcher(ctx, specs, after_start=after_start), WALL_LIMIT_S)
    result.pop("task").result()
    assert not [n for n, h in launcher.health.items() if h.restarts], launcher.health
    result["arrived"] = [e.data.get("place") for e in arrived]
    result["pose"] = ctx.resources[WORLD_RESOURCE].pose
    return result


@pytest.mark.slow
async def test_map_the_building_then_tour_it(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(PASSWORD_ENV, PASSWORD)
    mapped = await _map_phase(tmp_path)
    tour = mapped["tour"]
    maps = tmp_path / "maps"
    assert mapped["saved"]["yaml"] == str(maps / "hall.yaml")
    assert tour["profile"] == str(maps / "hall.profile.yaml")
    grid = read_map(maps / "hall.yaml")
    assert (grid.data == 100).sum() > 300  # the corridor's walls
    assert tour["places"] == 1  # MAPPING_START: the dock, where mapping began
    assert tour["command"] == f"sage sim --profile {maps / 'hall.profile.yaml'}"

    toured = await _tour_phase(tour["profile"])
    assert "IN_THE_WALL" in toured["refused"]
    assert "inside a wall" in toured["refused"], toured["refused"]
    assert toured["file"].endswith("hall.waypoints.yaml")
    assert sorted(toured["saved_maps"]) == ["autosave", "hall"]  # the tour's admin lists that folder
    assert "robot corner" in toured["reply"].lower(), toured["reply"]
    assert toured["arrived"] == ["ROBOT_CORNER"]
    x, y, _ = toured["pose"]
    assert math.hypot(x - NEW_PLACE["x"], y - NEW_PLACE["y"]) < ARRIVAL_TOLERANCE_M, toured["pose"]
    assert START_PLACE in (maps / "hall.waypoints.yaml").read_text()


def test_sage_slam_tour_writes_the_tour_profile(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`sage slam tour NAME`: the same as the admin's "Use as tour map", from the command line."""
    truth = loop_path(step_m=0.3)[:SYNTH_SCANS]
    drive = simulate(corridor_loop(), truth, yaw_drift=0.0)
    slam = Slam(initial_pose=truth[0])
    for k, (odom, scan) in enumerate(zip(drive.odom, drive.scans, strict=True)):
        slam.add_scan(0.1 * k, odom, scan)
    save_session(slam, tmp_path, "loop")
    profile = tmp_path / "robot.yaml"  # the old map's keepout mask must not follow the new map
    profile.write_text(f"nav: {{keepout_mask: {tmp_path / 'old_keepout.yaml'}}}\nweb: {{port: 8123}}\n")
    assert main(["--profile", str(profile), "slam", "tour", "loop", "--out", str(tmp_path)]) == 0
    written = tmp_path / "loop.profile.yaml"
    assert capsys.readouterr().out.splitlines()[-1] == f"tour it: sage sim --profile {written}"
    settings = load_profile(written)
    assert settings.nav.map == str(tmp_path / "loop.yaml")
    assert settings.nav.keepout_mask == ""
    assert settings.web.port == 8123  # the rest of the robot's profile is kept
    assert settings.nav.initial_place == START_PLACE
    assert settings.slam.out_dir == str(tmp_path)  # the tour's admin page lists these maps

    assert main(["slam", "tour", "nowhere", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"sage: error: no saved map 'nowhere' in {tmp_path}"
