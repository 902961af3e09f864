import asyncio
from typing import Any, cast

from sage_robot.app.launcher import Launcher, NodeSpec
from sage_robot.core.bus import Bus
from sage_robot.core.clock import SimClock
from sage_robot.core.config import load_profile
from sage_robot.core.msgs import Twist
from sage_robot.core.node import Node, NodeContext, NodeState


class Flaky(Node):
    name = "flaky"
    builds = 0
    torn_down = 0

    async def setup(self) -> None:
        type(self).builds += 1
        self.every(0.1, self._tick)

    def _tick(self) -> None:
        if type(self).builds <= 2:
            raise RuntimeError("sensor exploded")

    async def teardown(self) -> None:
        type(self).torn_down += 1


class Steady(Node):
    name = "steady"
    stopped = False

    async def teardown(self) -> None:
        type(self).stopped = True


async def test_crashing_node_is_restarted_and_health_shows_it():
    clock = SimClock()
    ctx = NodeContext(Bus(clock), clock, load_profile())
    stops: list[Twist] = []
    ctx.bus.subscribe("/cmd_vel", Twist, stops.append)
    launcher = Launcher(ctx, [NodeSpec("flaky", Flaky, critical=True), NodeSpec("steady", Steady)])
    await launcher.start()
    for _ in range(1000):  # 10 simulated seconds
        await clock.step(0.01)
    health = launcher.health_report()
    assert health["flaky"]["restarts"] == 2
    assert health["flaky"]["state"] == "running"
    assert "sensor exploded" in str(health["flaky"]["last_error"])
    assert Flaky.torn_down == 2
    assert stops, "a critical crash must command a stop"
    assert all(t.is_zero for t in stops), "a critical crash must command a stop"
    await launcher.stop()
    assert Steady.stopped
    assert all(h.state is NodeState.STOPPED for h in launcher.health.values())


async def test_request_stop_ends_run():
    clock = SimClock()
    ctx = NodeContext(Bus(clock), clock, load_profile())
    launcher = Launcher(ctx, [NodeSpec("steady", Steady)])
    runner = asyncio.ensure_future(launcher.run())
    await clock.step(0.1)
    launcher.request_stop()
    await asyncio.wait_for(runner, 2)
    assert launcher.health["steady"].state is NodeState.STOPPED


async def test_health_shows_each_nodes_topic_rates():
    from sage_robot.app.builtin import HeartbeatNode

    clock = SimClock()
    ctx = NodeContext(Bus(clock), clock, load_profile())
    launcher = Launcher(ctx, [NodeSpec("heartbeat", HeartbeatNode), NodeSpec("steady", Steady)])
    await launcher.start()
    for _ in range(500):  # 5 simulated seconds
        await clock.step(0.01)
    report = launcher.health_report()
    assert cast(dict[str, Any], report["heartbeat"]["topics"])["/sage/heartbeat"] == 1.0
    assert report["steady"]["topics"] == {}
    await launcher.stop()


async def test_health_goes_out_on_its_latched_topic_at_each_change():
    from sage_robot.core import topics
    from sage_robot.core.msgs import HealthReport

    Flaky.builds = 0
    clock = SimClock()
    ctx = NodeContext(Bus(clock), clock, load_profile())
    reports: list[HealthReport] = []
    ctx.bus.subscribe(topics.HEALTH, HealthReport, reports.append, maxsize=1000)
    launcher = Launcher(ctx, [NodeSpec("flaky", Flaky), NodeSpec("steady", Steady)])
    await launcher.start()
    await clock.step(0.01)
    latest = ctx.bus.latest(topics.HEALTH)
    assert latest is not None
    assert {h.name: h.state for h in latest.nodes} == {"flaky": "running", "steady": "running"}
    for _ in range(50):  # before the first diagnostics period: the crash alone publishes
        await clock.step(0.01)
    latest = ctx.bus.latest(topics.HEALTH)
    assert latest is not None
    flaky = next(h for h in latest.nodes if h.name == "flaky")
    assert flaky.restarts >= 1
    assert "sensor exploded" in flaky.last_error
    for _ in range(600):
        await clock.step(0.01)
    latest = ctx.bus.latest(topics.HEALTH)
    assert latest is not None
    report = launcher.health_report()
    assert {h.name: {**vars(h)} for h in latest.nodes} == report
    assert all(topics.HEALTH not in h.topics for h in latest.nodes)  # the launcher's, not a node's
    await launcher.stop()
    assert ctx.bus.latest(topics.HEALTH).nodes[0].state == "stopped"  # type: ignore[union-attr]
    assert len(reports) > 5
