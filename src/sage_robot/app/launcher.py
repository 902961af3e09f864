"""The launcher: starts a profile's nodes, restarts a crashed one with backoff, stops all.

Every node runs in its own supervised task. A node that raises is torn down, its health
records the error and the restart count, and it is built again after a delay that
doubles with each crash (reset once it has run for a while). When a *critical* node
(MCU link, navigator, teleop bridge) goes down, the launcher commands a stop on
``/cmd_vel`` and publishes an event, so no loss of command leaves the robot moving.

The health of every node goes out on ``/sage/health`` (latched; the web pages read it) when
a node changes state and once per diagnostics period, with ``/diagnostics`` beside it.
"""

from __future__ import annotations

import asyncio
import contextlib
import signal
from collections.abc import Callable
from dataclasses import dataclass

from sage_robot.core import topics
from sage_robot.core.bus import Bus, Topic
from sage_robot.core.log import get_logger
from sage_robot.core.msgs import (
    DiagnosticArray,
    DiagnosticStatus,
    Event,
    HealthReport,
    Level,
    NodeHealth,
    Twist,
)
from sage_robot.core.node import CURRENT_NODE, LAUNCHER, Health, Node, NodeContext, NodeState
from sage_robot.core.resources import ResourceKey

BACKOFF_INITIAL_S = 0.5
BACKOFF_MAX_S = 10.0
STABLE_AFTER_S = 30.0  # a node that ran this long starts again from the initial backoff
DIAGNOSTICS_PERIOD_S = 1.0
TEARDOWN_TIMEOUT_S = 3.0
HEALTH_TOPIC: ResourceKey[Topic[HealthReport]] = ResourceKey("health_topic", doc="where the launcher reports")

_LEVEL = {
    NodeState.RUNNING: Level.OK,
    NodeState.STARTING: Level.WARN,
    NodeState.BACKOFF: Level.ERROR,
    NodeState.FAILED: Level.ERROR,
    NodeState.STOPPED: Level.STALE,
    NodeState.CREATED: Level.STALE,
}


@dataclass
class NodeSpec:
    """One node of a profile."""

    name: str
    factory: Callable[[NodeContext], Node]
    critical: bool = False  # its loss must stop the robot
    restart: bool = True


class Launcher:
    def __init__(
        self, ctx: NodeContext, specs: list[NodeSpec], health_topic: Topic[HealthReport] | None = None
    ) -> None:
        names = [s.name for s in specs]
        if len(set(names)) != len(names):
            raise ValueError(f"duplicate node names in {names}")
        self.ctx, self.specs = ctx, specs
        # A process group reports on its own topic (app.group_main); the supervisor merges them.
        self.health_topic = health_topic or ctx.resources.get(HEALTH_TOPIC) or topics.HEALTH
        self.bus: Bus = ctx.bus
        self.log = get_logger("launcher")
        self.health: dict[str, Health] = {s.name: Health(s.name, critical=s.critical) for s in specs}
        self.nodes: dict[str, Node] = {}
        self._tasks: dict[str, asyncio.Task[None]] = {}
        self._stopping = False
        self._stop_event = asyncio.Event()
        self._published: dict[tuple[str, str], int] = {}  # (node, topic) -> messages
        self._rates: dict[tuple[str, str], float] = {}  # (node, topic) -> Hz over the last period
        self._rate_base: tuple[float, dict[tuple[str, str], int]] = (ctx.clock.now(), {})
        self._remove_tap = ctx.bus.add_tap(self._count)
        self.bus.declare(self.health_topic, latched=True)
        ctx.resources[LAUNCHER] = self

    # ---------------------------------------------------------------- public
    async def start(self) -> None:
        """Start every node (each in its own supervised task) and the diagnostics timer."""
        for spec in self.specs:
            self._tasks[spec.name] = asyncio.get_running_loop().create_task(
                self._supervise(spec), name=f"supervise:{spec.name}"
            )
        self._diag = self.ctx.clock.every(DIAGNOSTICS_PERIOD_S, self._publish_diagnostics, "diagnostics")
        self._publish_health()

    async def run(self) -> None:
        """Start, then wait until :meth:`request_stop` (or a signal), then stop cleanly."""
        await self.start()
        await self._stop_event.wait()
        await self.stop()

    def request_stop(self) -> None:
        self._stop_event.set()

    def node_names(self) -> list[str]:
        return [s.name for s in self.specs]

    def install_signal_handlers(self) -> None:
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            with contextlib.suppress(NotImplementedError, RuntimeError):
                loop.add_signal_handler(sig, self.request_stop)

    async def stop(self) -> None:
        """Stop every node (reverse order), tearing each down."""
        self._stopping = True
        if hasattr(self, "_diag"):
            self._diag.cancel()
        for spec in reversed(self.specs):
            task = self._tasks.get(spec.name)
            if task and not task.done():
                task.cancel()
                with contextlib.suppress(asyncio.CancelledError, Exception):
                    await task
            self.health[spec.name].state = NodeState.STOPPED
        self._publish_diagnostics()
        self._remove_tap()

    def health_report(self) -> dict[str, dict[str, object]]:
        """Every node: state, restarts, last error, its own stats and its topics' rates (Hz)."""
        self._refresh_stats()
        return {name: {**h.as_dict(), "topics": self.topic_rates(name)} for name, h in self.health.items()}

    def health_msg(self) -> HealthReport:
        """:meth:`health_report` as the message published on ``/sage/health``."""
        self._refresh_stats()
        nodes = tuple(
            NodeHealth(
                h.name,
                h.state.value,
                h.restarts,
                h.last_error,
                h.started_at,
                h.critical,
                dict(h.stats),
                self.topic_rates(name),
            )
            for name, h in self.health.items()
        )
        return HealthReport(self.ctx.clock.now(), nodes)

    def _refresh_stats(self) -> None:
        for name, node in self.nodes.items():
            with contextlib.suppress(Exception):
                self.health[name].stats = node.stats()

    # ---------------------------------------------------------------- internals
    def _count(self, topic: str, msg: object) -> None:
        key = (CURRENT_NODE.get(), topic)
        self._published[key] = self._published.get(key, 0) + 1

    def _update_rates(self) -> None:
        now = self.ctx.clock.now()
        t0, base = self._rate_base
        if now - t0 <= 0:
            return
        self._rates = {k: (n - base.get(k, 0)) / (now - t0) for k, n in self._published.items()}
        self._rate_base = (now, dict(self._published))

    def topic_rates(self, node: str = "") -> dict[str, float]:
        """Hz of the topics a node published over the last diagnostics period."""
        return {t: round(hz, 2) for (n, t), hz in self._rates.items() if n == node}

    async def _supervise(self, spec: NodeSpec) -> None:
        CURRENT_NODE.set(spec.name)  # this task's context: inherited by everything the node creates
        health = self.health[spec.name]
        backoff = BACKOFF_INITIAL_S
        clock = self.ctx.clock
        while not self._stopping:
            health.state = NodeState.STARTING
            self._publish_health()
            node: Node | None = None
            started = clock.now()
            try:
                node = spec.factory(self.ctx)
                self.nodes[spec.name] = node
                await node.setup()
                health.state, health.started_at = NodeState.RUNNING, clock.now()
                self.log.info("node running", node=spec.name)
                self._publish_health()
                await node.run()
                health.state = NodeState.STOPPED
                self.log.info("node finished", node=spec.name)
                self._publish_health()
                return
            except asyncio.CancelledError:
                raise
            except Exception as exc:
                health.last_error = f"{type(exc).__name__}: {exc}"
                self.log.exception("node crashed", node=spec.name, restarts=health.restarts)
                self._on_down(spec, health.last_error)
            finally:
                if node is not None:
                    await self._teardown(spec.name, node)
            if not spec.restart:
                health.state = NodeState.FAILED
                self._publish_health()
                return
            if clock.now() - started > STABLE_AFTER_S:
                backoff = BACKOFF_INITIAL_S
            health.state = NodeState.BACKOFF
            health.restarts += 1
            self._publish_health()
            self.log.warning("restarting node", node=spec.name, delay_s=round(backoff, 2))
            await clock.sleep(backoff)
            backoff = min(backoff * 2, BACKOFF_MAX_S)

    async def _teardown(self, name: str, node: Node) -> None:
        try:
            await asyncio.wait_for(asyncio.shield(self._teardown_inner(node)), TEARDOWN_TIMEOUT_S)
        except Exception:
            self.log.exception("teardown failed", node=name)

    @staticmethod
    async def _teardown_inner(node: Node) -> None:
        try:
            await node.teardown()
        finally:
            await node._close()

    def _on_down(self, spec: NodeSpec, reason: str) -> None:
        if not spec.critical:
            return
        self.log.error("critical node down: stopping the robot", node=spec.name)
        self.bus.publish(topics.CMD_VEL, Twist())
        self.bus.publish(
            topics.EVENTS,
            Event(self.ctx.clock.now(), "launcher", "safety_stop", f"{spec.name} is down: {reason}"),
        )

    def _publish_diagnostics(self) -> None:
        self._update_rates()
        report = self.health_report()
        status = tuple(
            DiagnosticStatus(
                name,
                _LEVEL[self.health[name].state],
                h["last_error"] or h["state"],  # type: ignore[arg-type]
                {"restarts": str(h["restarts"]), "state": str(h["state"])},
            )
            for name, h in report.items()
        )
        self.bus.publish(topics.DIAGNOSTICS, DiagnosticArray(self.ctx.clock.now(), status))
        self._publish_health()

    def _publish_health(self) -> None:
        """The health of every node on ``/sage/health``, as the launcher's own publication
        (not counted as the node's whose state just changed)."""
        token = CURRENT_NODE.set("")
        try:
            self.bus.publish(self.health_topic, self.health_msg())
        except Exception:  # a report that cannot go out must not stop the supervision
            self.log.exception("cannot publish the health report")
        finally:
            CURRENT_NODE.reset(token)
