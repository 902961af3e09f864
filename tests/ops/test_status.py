"""`sage status` against a real web server of a running launcher (a node that keeps crashing shows)."""

import asyncio
import subprocess
import sys

from sage_robot.app.builtin import HeartbeatNode
from sage_robot.app.launcher import Launcher, NodeSpec
from sage_robot.core.bus import Bus
from sage_robot.core.clock import WallClock
from sage_robot.core.config import load_profile
from sage_robot.core.node import Node, NodeContext
from sage_robot.web.node import WEB_URL, WebNode

from ..support.waits import until


class Broken(Node):
    name = "broken"

    async def setup(self) -> None:
        raise RuntimeError("lidar cable chewed")


async def test_status_prints_every_node_and_fails_on_a_broken_one():
    settings = load_profile(None, {"web": {"port": 0, "host": "127.0.0.1"}})
    clock = WallClock()
    ctx = NodeContext(Bus(clock), clock, settings)
    launcher = Launcher(
        ctx, [NodeSpec("heartbeat", HeartbeatNode), NodeSpec("broken", Broken), NodeSpec("web", WebNode)]
    )
    await launcher.start()
    try:
        url = await until(lambda: ctx.resources.get(WEB_URL), "the web server's address")
        proc = await asyncio.create_subprocess_exec(
            sys.executable,
            "-m",
            "sage_robot.cli.main",
            "status",
            "--url",
            url,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
        )
        out, err = await asyncio.wait_for(proc.communicate(), 60)
    finally:
        await launcher.stop()
    text = out.decode()
    assert proc.returncode == 1, err.decode()
    assert "heartbeat" in text
    assert "running" in text
    assert "broken" in text
    assert "backoff" in text or "starting" in text


def test_status_without_a_robot_is_one_clear_line():
    out = subprocess.run(
        [sys.executable, "-m", "sage_robot.cli.main", "status", "--url", "http://127.0.0.1:9"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 2
    assert "no robot answers" in out.stderr
    assert "Traceback" not in out.stderr
