"""`sage slam save NAME` reaching a running session: the real web node (uvicorn on a free
loopback port) and the slam node on one bus, the CLI posting from a worker thread."""

from __future__ import annotations

import asyncio
import json
import urllib.error
import urllib.request
from pathlib import Path
from typing import Any

import pytest

from sage_robot.cli.main import main
from sage_robot.core.bus import Bus
from sage_robot.core.clock import SimClock
from sage_robot.core.config import load_profile
from sage_robot.core.mapio import read_map
from sage_robot.core.node import Node, NodeContext
from sage_robot.nav.slam.messages import SlamProgress
from sage_robot.nav.slam.node import OUT_DIR_RESOURCE, SLAM_PROGRESS, SLAM_SAVE, SlamNode
from sage_robot.web.auth import PASSWORD_ENV
from sage_robot.web.node import WebNode

from .synth import corridor_loop, loop_path, publish_step, simulate

WAIT_S = 20.0  # bound on every wait (a loaded 2-core machine)
SCANS = 12
PASSWORD = "slam-test-pw"


def _get(url: str) -> tuple[int, dict[str, Any]]:
    try:
        with urllib.request.urlopen(url, timeout=WAIT_S) as resp:
            return resp.status, json.load(resp)
    except urllib.error.HTTPError as exc:
        return exc.code, json.load(exc)


async def _cli(args: list[str]) -> int:
    return await asyncio.wait_for(asyncio.to_thread(main, args), WAIT_S * 2)


async def test_save_a_running_session_over_http(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
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
    web, slam = WebNode(ctx), SlamNode(ctx)
    nodes: list[Node] = [web, slam]
    for node in nodes:
        await node.setup()
    url = web.url
    try:
        # Before any scan: running, nothing mapped yet; the operator's login is required.
        status, body = await asyncio.to_thread(_get, url + "/api/slam/progress")
        assert status == 401
        assert "log in" in body["error"]

        progress = bus.subscribe(SLAM_PROGRESS, SlamProgress, maxsize=100)
        drive = simulate(corridor_loop(), loop_path(step_m=0.3)[:SCANS], yaw_drift=0.0)
        for k in range(SCANS):
            await publish_step(bus, clock, drive, k)
            await asyncio.wait_for(progress.get(), WAIT_S)

        assert await _cli(["slam", "save", "live", "--url", url]) == 0
        out = capsys.readouterr().out
        yaml_path = tmp_path / "maps" / "live.yaml"
        assert f"map: {yaml_path}" in out
        grid = read_map(yaml_path)
        assert (grid.data == 100).sum() > 200  # the corridor's walls
        assert (tmp_path / "maps" / "live.graph.npz").exists()
        assert len((tmp_path / "maps" / "live.trajectory.txt").read_text().splitlines()) == SCANS + 1

        # The progress the page shows, through a logged-in session.
        opener = urllib.request.build_opener(urllib.request.HTTPCookieProcessor())
        login = urllib.request.Request(  # a JSON body says so (text/plain is refused: 415)
            url + "/api/login", json.dumps({"password": PASSWORD}).encode(),
            {"Content-Type": "application/json"}, method="POST",
        )
        await asyncio.to_thread(opener.open, login, None, WAIT_S)
        with await asyncio.to_thread(opener.open, url + "/api/slam/progress", None, WAIT_S) as resp:
            seen = json.load(resp)
        assert seen["running"] is True
        assert seen["scans"] == SCANS
        assert seen["keyframes"] >= SCANS // 2

        # Refusals are one line each, and nothing is written.
        assert await _cli(["slam", "save", "../up", "--url", url]) == 2
        assert "use letters" in capsys.readouterr().err
        assert await _cli(["slam", "save", "x", "--url", url, "--out", str(tmp_path)]) == 2
        assert "--out goes with --from" in capsys.readouterr().err
        monkeypatch.setenv(PASSWORD_ENV, "wrong")
        assert await _cli(["slam", "save", "y", "--url", url]) == 2
        err = capsys.readouterr().err.strip().splitlines()[-1]  # the server logs here too
        assert err.startswith("sage: error: ")
        assert err.endswith("/api/login: 401 wrong password")
        monkeypatch.setenv(PASSWORD_ENV, PASSWORD)
        bus.unserve(SLAM_SAVE)  # as if no slam node ran (e.g. tour mode)
        assert await _cli(["slam", "save", "z", "--url", url]) == 2
        assert "503 SLAM is not running" in capsys.readouterr().err
        assert sorted(p.name for p in (tmp_path / "maps").iterdir()) == [
            "live.graph.npz",
            "live.pgm",
            "live.trajectory.txt",
            "live.yaml",
        ]
    finally:
        for node in reversed(nodes):
            await node.teardown()
            await node._close()
    # Nobody answers any more: one clear line.
    assert await _cli(["slam", "save", "gone", "--url", url]) == 2
    assert "no robot answers at" in capsys.readouterr().err
