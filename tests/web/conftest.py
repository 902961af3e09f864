"""The web server on the simulator, in a background thread, for real-browser tests.

One :class:`SimRobot` per test module: SimClock at real-time speed, the simulator's
firmware model behind a pty (``mcu_sim``), the real serial bridge and the web node on a
free loopback port, plus whatever of the simulated world and navigation is registered.
A hand-drawn map is published when no map server runs, and a test ``navigate_to``
server stands in when the navigator is not registered (the tests say which ran).
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import json
import os
import shutil
import threading
from collections.abc import Callable, Coroutine, Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from sage_robot.app.launcher import NodeSpec
from sage_robot.app.profiles import PROFILES
from sage_robot.app.registry import NODES, node_class
from sage_robot.app.runtime import make_context, run_launcher
from sage_robot.brain.base import Utterance
from sage_robot.core import topics
from sage_robot.core.actions import GoalContext
from sage_robot.core.config import load_profile
from sage_robot.core.errors import ConfigError
from sage_robot.core.mapio import read_map
from sage_robot.core.msgs import OccupancyGrid, Odometry, Pose2D, Text
from sage_robot.core.msgs.nav import NavigateGoal, NavigateResult
from sage_robot.core.node import NodeState
from sage_robot.core.paths import DEFAULT_BUILDING, map_yaml, package_data
from sage_robot.core.places import Place, Places, write_places
from sage_robot.web.node import WEB_URL

from ..support.grids import fill, room
from ..support.waits import until

PASSWORD = "test-operator-pw"
START_TIMEOUT_S = 20.0
CALL_TIMEOUT_S = 10.0
CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
    "--use-fake-ui-for-media-stream",
    "--use-fake-device-for-media-stream",
    "--autoplay-policy=no-user-gesture-required",  # the kiosk tablet is set up so
]
MAP_RES_M = 0.05
WORLD_NODES = ("sim_world", "map_server", "localization", "navigator", "brain")  # when registered


def artifacts_dir() -> Path:
    path = Path(os.environ.get("SAGE_ARTIFACTS", "/tmp/sage-artifacts")) / "web"
    path.mkdir(parents=True, exist_ok=True)
    return path


def hand_drawn_map() -> OccupancyGrid:
    """A 10 m x 6 m room with walls, origin at (-2, -3): the robot starts at (0, 0) facing +x."""
    grid = room(10.0, 6.0, MAP_RES_M, wall_cells=2, origin=(-2.0, -3.0))
    return fill(grid, 5.0, -1.0, 5.5, 0.0)  # a pillar


class SimRobot:
    """The running system; test code calls into its loop thread-safely."""

    def __init__(self, tmp: Path, *, with_converse: bool = True, mcu: dict[str, Any] | None = None,
                 web: dict[str, Any] | None = None, extra_nodes: tuple[str, ...] = ()) -> None:
        self.tmp = tmp
        self.web = web or {}  # profile overrides of the web section (e.g. tls: on)
        self.extra_nodes = extra_nodes  # more registered nodes to run (e.g. "voice")
        self.mcu = mcu or {}  # profile overrides of the mcu section (e.g. the firmware dialect)
        self.with_converse = with_converse
        self.loop = asyncio.new_event_loop()
        self.ready = threading.Event()
        self.error: BaseException | None = None
        self.odom: Odometry | None = None
        self.goals: list[NavigateGoal] = []
        self.questions: list[str] = []
        self.stand_ins: list[str] = []
        self.missing: list[str] = []
        self.password = PASSWORD
        self.artifacts = artifacts_dir()
        self.thread = threading.Thread(target=self._thread, name="sim-robot", daemon=True)

    # ------------------------------------------------------------ lifecycle
    def start(self) -> SimRobot:
        self.thread.start()
        if not self.ready.wait(START_TIMEOUT_S):
            raise RuntimeError(f"the simulated robot did not start within {START_TIMEOUT_S} s: {self.error}")
        if self.error:
            raise RuntimeError(f"the simulated robot failed: {self.error}")
        return self

    def stop(self) -> None:
        if self.loop.is_running():
            self.loop.call_soon_threadsafe(self.launcher.request_stop)
        self.thread.join(10)

    def _thread(self) -> None:
        asyncio.set_event_loop(self.loop)
        try:
            self.loop.run_until_complete(self._main())
        except BaseException as exc:
            self.error = exc
            self.ready.set()

    async def _main(self) -> None:
        waypoints = self.tmp / "waypoints.yaml"
        shipped = package_data("maps", DEFAULT_BUILDING, "waypoints.yaml")
        if shipped.exists():  # a copy: the admin test adds a place to it
            shutil.copy(shipped, waypoints)
        else:
            write_places(Places([Place("LOBBY", Pose2D(3.0, 1.0, 0.0), "the front hall")]), waypoints)
        settings = load_profile(
            None,
            {
                "web": {"host": "127.0.0.1", "port": 0, **self.web},
                "nav": {"waypoints": str(waypoints)},
                "sim": {"speed": 1.0},
                **({"mcu": self.mcu} if self.mcu else {}),
            },
        )
        self.ctx = make_context(settings, simulated=True)
        self.bus = self.ctx.bus
        critical = dict(PROFILES["sim"])
        world = [n for n in WORLD_NODES if n in NODES]
        wanted = [*world, *self.extra_nodes, "mcu_sim", "serial_bridge", "web"]
        specs = []
        for name in wanted:
            try:
                specs.append(NodeSpec(name, node_class(name), critical.get(name, False)))
            except ConfigError:  # registered but its module has not landed yet
                self.missing.append(name)
        self.node_names = [s.name for s in specs]

        async def after_start(launcher: Any) -> None:
            self.launcher = launcher
            with contextlib.suppress(AssertionError):  # a node that never runs shows in the tests
                await until(lambda: all(h.state is NodeState.RUNNING for h in launcher.health.values()),
                            "every node to run", START_TIMEOUT_S, poll=0.05)
            self.bus.subscribe(topics.ODOM, Odometry, self._on_odom)
            if "map_server" not in self.node_names:
                self.stand_ins.append("map")
                self.bus.declare(topics.MAP, OccupancyGrid, latched=True)
                shipped_map = map_yaml(settings)
                grid = read_map(shipped_map) if shipped_map.exists() else hand_drawn_map()
                self.bus.publish(topics.MAP, grid)
            if "navigator" not in self.node_names:
                self.stand_ins.append("navigate_to")
                self.bus.actions.serve(topics.NAVIGATE_TO, self._navigate)
            if self.with_converse and not self.bus.actions.has(topics.CONVERSE):
                self.stand_ins.append("converse")
                self.bus.actions.serve(topics.CONVERSE, self._converse)
            self.url = await until(lambda: self.ctx.resources.get(WEB_URL), "the web server's address",
                                   START_TIMEOUT_S, poll=0.05)
            report = {"nodes": self.node_names, "stand_ins": self.stand_ins, "not_landed": self.missing}
            (self.artifacts / "run.json").write_text(json.dumps(report, indent=1))
            self.ready.set()

        try:
            await run_launcher(self.ctx, specs, after_start=after_start)
        finally:
            rest = [t for t in asyncio.all_tasks() if t is not asyncio.current_task()]
            for t in rest:
                t.cancel()
            await asyncio.gather(*rest, return_exceptions=True)

    # ------------------------------------------------------------ stand-ins
    async def _navigate(self, goal: NavigateGoal, ctx: GoalContext) -> NavigateResult:
        """Drives straight at 0.3 m/s for as long as the goal runs (no planner here)."""
        from sage_robot.core.msgs import Twist

        self.goals.append(goal)
        try:
            for _ in range(100):
                self.bus.publish(topics.CMD_VEL, Twist(0.3, 0.0))
                await self.ctx.clock.sleep(0.1)
        finally:
            self.bus.publish(topics.CMD_VEL, Twist(0.0, 0.0))
        return NavigateResult(True, goal.place)

    async def _converse(self, goal: Text | Utterance, ctx: GoalContext) -> Text:
        heard = goal.data if isinstance(goal, Text) else goal.text
        self.questions.append(heard)
        reply = f"You asked about {heard.rstrip('?')}. It is on the first floor."
        ctx.feedback(Text(reply))
        return Text(reply)

    def _on_odom(self, msg: Odometry) -> None:
        self.odom = msg

    # ------------------------------------------------------------ thread-safe helpers
    def run(self, coro: Coroutine[Any, Any, Any], timeout: float = CALL_TIMEOUT_S) -> Any:
        return asyncio.run_coroutine_threadsafe(coro, self.loop).result(timeout)

    def call(self, fn: Callable[[], Any], timeout: float = CALL_TIMEOUT_S) -> Any:
        fut: concurrent.futures.Future[Any] = concurrent.futures.Future()

        def inner() -> None:
            try:
                fut.set_result(fn())
            except BaseException as exc:
                fut.set_exception(exc)

        self.loop.call_soon_threadsafe(inner)
        return fut.result(timeout)

    def publish(self, topic: str, msg: Any) -> None:
        self.call(lambda: self.bus.publish(topic, msg))

    def web_node(self) -> Any:
        return self.launcher.nodes["web"]


@contextlib.contextmanager
def operator_env(state_dir: Path) -> Iterator[None]:
    """The test operator password and ``state_dir`` in the environment, restored after."""
    old = {k: os.environ.get(k) for k in ("SAGE_OPERATOR_PASSWORD", "SAGE_STATE_DIR")}
    os.environ["SAGE_OPERATOR_PASSWORD"] = PASSWORD
    os.environ["SAGE_STATE_DIR"] = str(state_dir)
    try:
        yield
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


@contextlib.contextmanager
def sim_robot(tmp_path_factory: pytest.TempPathFactory, name: str, **kw: Any) -> Iterator[SimRobot]:
    """A started :class:`SimRobot` with the test operator password and its own state folder."""
    tmp = tmp_path_factory.mktemp(name)
    with operator_env(tmp / "state"):
        sim = SimRobot(tmp, **kw).start()
        try:
            yield sim
        finally:
            sim.stop()


@pytest.fixture(scope="module")
def robot(tmp_path_factory: pytest.TempPathFactory) -> Iterator[SimRobot]:
    with sim_robot(tmp_path_factory, "web") as sim:
        yield sim


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    if not Path(CHROMIUM).exists():
        pytest.fail(f"{CHROMIUM} is missing: apt-get install chromium (see scripts/apt-packages.txt)")
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        b = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS, headless=True)
        try:
            yield b
        finally:
            with contextlib.suppress(Exception):
                b.close()


@pytest.fixture(scope="module")
def client(robot: SimRobot) -> Iterator[httpx.Client]:
    """HTTP to the module's robot (not logged in)."""
    with httpx.Client(base_url=robot.url, timeout=30.0) as c:
        yield c


@pytest.fixture(scope="module")
def cookie(robot: SimRobot) -> str:
    """The operator's session cookie, from the login API."""
    resp = httpx.post(f"{robot.url}/api/login", json={"password": robot.password})
    assert resp.status_code == 200
    return f"sage_session={resp.cookies['sage_session']}"
