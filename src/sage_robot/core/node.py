"""Nodes: the units the launcher starts, watches and restarts.

A node subclasses :class:`Node` and fills in ``setup`` (subscribe, open devices),
optionally ``run`` (its main loop; by default it waits for its timers and
subscriptions) and ``teardown`` (always called: stop motors, close ports). Timers and
tasks made with :meth:`Node.every` / :meth:`Node.spawn` belong to the node: if one
raises, the node fails and the launcher restarts it.
"""

from __future__ import annotations

import asyncio
import contextvars
import threading
from collections.abc import Callable, Coroutine
from dataclasses import dataclass, field
from enum import Enum
from typing import Any, Protocol, TypeVar, overload

from sage_robot.core.bus import Bus, PlainName, Subscription, Topic
from sage_robot.core.clock import Clock, Timer
from sage_robot.core.config import Settings
from sage_robot.core.log import StructLogger, get_logger
from sage_robot.core.resources import ResourceKey, Resources

M = TypeVar("M")

# The node whose code is running: set by the launcher in each node's task, inherited by the
# tasks, timers, subscriptions and (through Node.start_thread) threads the node creates, so
# every publication can be attributed to its node for the health record's topic rates.
CURRENT_NODE: contextvars.ContextVar[str] = contextvars.ContextVar("sage_current_node", default="")


StepHook = Callable[[float], Any]

# Callables(dt) the simulator's stepper runs before each simulated step (physics of the
# world and the firmware model). Here, in core, so sim and app share it.
SIM_STEP_HOOKS: ResourceKey[list[StepHook]] = ResourceKey("sim_step_hooks", list)


class LauncherHandle(Protocol):
    """What a node may ask of the launcher that runs it (``ctx.resources[LAUNCHER]``)."""

    def node_names(self) -> list[str]:
        """The nodes of this launch, running or not."""
        ...

    def request_stop(self) -> None:
        """Stop every node and end the run."""
        ...


LAUNCHER: ResourceKey[LauncherHandle] = ResourceKey("launcher", doc="set by the launcher")


class NodeState(str, Enum):
    CREATED = "created"
    STARTING = "starting"
    RUNNING = "running"
    BACKOFF = "backoff"  # crashed, waiting to restart
    STOPPED = "stopped"
    FAILED = "failed"  # gave up (or not restartable)


@dataclass
class Health:
    """What the launcher knows of a node (shown on the web home page and `sage status`)."""

    name: str
    state: NodeState = NodeState.CREATED
    restarts: int = 0
    last_error: str = ""
    started_at: float | None = None
    critical: bool = False
    stats: dict[str, Any] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "state": self.state.value,
            "restarts": self.restarts,
            "last_error": self.last_error,
            "started_at": self.started_at,
            "critical": self.critical,
            "stats": self.stats,
        }


@dataclass
class NodeContext:
    """Everything a node is given."""

    bus: Bus
    clock: Clock
    settings: Settings
    # Objects shared between nodes of one process that are not messages (e.g. the
    # simulated world for simulator nodes), by typed key (declared where the owner is).
    resources: Resources = field(default_factory=Resources)


class Node:
    """Base class of every node."""

    name: str = "node"

    def __init__(self, ctx: NodeContext) -> None:
        self.ctx = ctx
        self.bus, self.clock, self.settings = ctx.bus, ctx.clock, ctx.settings
        self.log: StructLogger = get_logger(self.name)
        self._tasks: list[asyncio.Task[Any]] = []
        self._subs: list[Subscription[Any]] = []

    # -------------------------------------------------------- to override
    async def setup(self) -> None:
        """Subscribe, offer services, open devices. Raise to fail the start."""

    async def run(self) -> None:
        """Main loop. The default waits until one of the node's tasks fails."""
        await self.wait_tasks()

    async def teardown(self) -> None:
        """Release everything; called after run ends or fails. Must not raise."""

    def stats(self) -> dict[str, Any]:
        """Node-specific numbers for the health record (rates, counters)."""
        return {}

    # -------------------------------------------------------- helpers
    def every(self, period_s: float, callback: Callable[[], Any], name: str = "") -> Timer:
        timer = self.clock.every(period_s, callback, name or f"{self.name}.timer")
        self._tasks.append(timer.task)
        return timer

    def spawn(self, coro: Coroutine[Any, Any, Any], name: str = "") -> asyncio.Task[Any]:
        task = asyncio.get_running_loop().create_task(coro, name=name or f"{self.name}.task")
        self._tasks.append(task)
        return task

    def start_thread(self, target: Callable[[], Any], name: str = "") -> threading.Thread:
        """A daemon thread (a driver's RX loop) that publishes as this node."""
        ctx = contextvars.copy_context()
        thread = threading.Thread(
            target=ctx.run, args=(target,), name=name or f"{self.name}.thread", daemon=True
        )
        thread.start()
        return thread

    @overload
    def subscribe(
        self,
        topic: Topic[M],
        msg_type: type[M],
        callback: Callable[[M], Any] | None = None,
        maxsize: int = 10,
    ) -> Subscription[M]: ...
    @overload
    def subscribe(
        self,
        topic: PlainName,
        msg_type: type[M],
        callback: Callable[[M], Any] | None = None,
        maxsize: int = 10,
    ) -> Subscription[M]: ...
    def subscribe(
        self,
        topic: Any,
        msg_type: type[M],
        callback: Callable[[M], Any] | None = None,
        maxsize: int = 10,
    ) -> Subscription[M]:
        """Subscribe for the node's lifetime (closed when the node stops)."""
        sub = self.bus.subscribe(topic, msg_type, callback, maxsize)
        self._subs.append(sub)
        return sub

    @overload
    def publish(self, topic: Topic[M], msg: M) -> None: ...
    @overload
    def publish(self, topic: PlainName, msg: Any) -> None: ...
    def publish(self, topic: Any, msg: Any) -> None:
        self.bus.publish(topic, msg)

    async def wait_tasks(self) -> None:
        """Wait forever, or until one of the node's tasks raises (then re-raise it)."""
        while True:
            live = [t for t in self._tasks if not t.done()]
            for t in self._tasks:
                if t.done() and not t.cancelled() and t.exception() is not None:
                    raise t.exception()  # type: ignore[misc]
            if not live:
                await asyncio.Event().wait()
            await asyncio.wait(live, return_when=asyncio.FIRST_COMPLETED)

    async def _close(self) -> None:
        for sub in self._subs:
            sub.close()
        for task in self._tasks:
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        self._tasks.clear()
        self._subs.clear()
