"""Actions: long-running goals with a feedback stream, cancel and a result (ROS 2 semantics).

A server is ``async def handler(goal, ctx) -> result``. It sends feedback with
``ctx.feedback(msg)``; a cancel arrives as ``asyncio.CancelledError`` inside the handler
(clean up in ``finally``); raising :class:`ActionAborted` ends the goal as aborted with a
reason a person understands. One goal runs at a time per server: a new goal preempts the
running one, whose client sees ``PREEMPTED``.
"""

from __future__ import annotations

import asyncio
import itertools
import logging
from collections import deque
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from enum import Enum
from typing import TYPE_CHECKING, Any

from sage_robot.core.errors import ServiceUnavailable

if TYPE_CHECKING:
    from sage_robot.core.bus import Bus

FEEDBACK_QUEUE = 32  # feedback messages kept per goal before the oldest is dropped

_log = logging.getLogger("sage.actions")


class GoalStatus(str, Enum):
    EXECUTING = "executing"
    SUCCEEDED = "succeeded"
    CANCELED = "canceled"
    PREEMPTED = "preempted"
    ABORTED = "aborted"

    @property
    def done(self) -> bool:
        return self is not GoalStatus.EXECUTING


class ActionAborted(Exception):
    """Raised by a handler to end its goal as aborted; the message is the reason."""


@dataclass(frozen=True)
class ActionResult:
    status: GoalStatus
    value: Any = None
    message: str = ""

    @property
    def ok(self) -> bool:
        return self.status is GoalStatus.SUCCEEDED


class GoalContext:
    """What a handler gets besides its goal."""

    def __init__(self, handle: GoalHandle) -> None:
        self._handle = handle

    @property
    def goal_id(self) -> int:
        return self._handle.goal_id

    def feedback(self, msg: Any) -> None:
        self._handle._push_feedback(msg)


class GoalHandle:
    """The client's view of one goal."""

    def __init__(self, goal_id: int, goal: Any) -> None:
        self.goal_id, self.goal = goal_id, goal
        self.status = GoalStatus.EXECUTING
        self._feedback: deque[Any] = deque(maxlen=FEEDBACK_QUEUE)
        self._changed = asyncio.Event()
        self._result: ActionResult | None = None
        self._task: asyncio.Task[None] | None = None
        self._cancel_status = GoalStatus.CANCELED
        self.last_feedback: Any = None

    def _push_feedback(self, msg: Any) -> None:
        self._feedback.append(msg)
        self.last_feedback = msg
        self._changed.set()

    def _finish(self, result: ActionResult) -> None:
        self._result = result
        self.status = result.status
        self._changed.set()

    @property
    def done(self) -> bool:
        return self._result is not None

    async def result(self) -> ActionResult:
        while self._result is None:
            self._changed.clear()
            await self._changed.wait()
        return self._result

    async def feedback(self) -> Any:
        """Async iterator over feedback until the goal ends."""
        while True:
            while self._feedback:
                yield self._feedback.popleft()
            if self._result is not None:
                return
            self._changed.clear()
            await self._changed.wait()

    async def cancel(self, status: GoalStatus = GoalStatus.CANCELED) -> ActionResult:
        """Ask the server to stop this goal and wait for it to wind down."""
        if self._task is not None and not self._task.done():
            self._cancel_status = status
            self._task.cancel()
        return await self.result()


Handler = Callable[[Any, GoalContext], Awaitable[Any]]


class ActionServer:
    def __init__(self, name: str, handler: Handler) -> None:
        self.name, self.handler = name, handler
        self.active: GoalHandle | None = None
        self.counts = {s: 0 for s in GoalStatus}

    async def _run(self, handle: GoalHandle) -> None:
        try:
            value = await self.handler(handle.goal, GoalContext(handle))
            result = ActionResult(GoalStatus.SUCCEEDED, value)
        except asyncio.CancelledError:
            result = ActionResult(handle._cancel_status, None, handle._cancel_status.value)
        except ActionAborted as exc:
            result = ActionResult(GoalStatus.ABORTED, None, str(exc))
        except Exception as exc:
            _log.exception("action %s failed", self.name)
            result = ActionResult(GoalStatus.ABORTED, None, f"internal error: {exc}")
        finally:
            if self.active is handle:
                self.active = None
        self.counts[result.status] += 1
        handle._finish(result)


class ActionRegistry:
    """The bus's action servers (``bus.actions``)."""

    def __init__(self, bus: Bus) -> None:
        self._bus = bus
        self._servers: dict[str, ActionServer] = {}
        self._ids = itertools.count(1)

    def serve(self, name: str, handler: Handler) -> ActionServer:
        if name in self._servers:
            raise ValueError(f"action {name} is already served")
        server = self._servers[name] = ActionServer(name, handler)
        return server

    def unserve(self, name: str) -> None:
        server = self._servers.pop(name, None)
        if server and server.active and server.active._task:
            server.active._task.cancel()

    def has(self, name: str) -> bool:
        return name in self._servers

    def active(self, name: str) -> GoalHandle | None:
        server = self._servers.get(name)
        return server.active if server else None

    async def send_goal(self, name: str, goal: Any) -> GoalHandle:
        """Start a goal; a running goal on the same server is preempted first."""
        server = self._servers.get(name)
        if server is None:
            raise ServiceUnavailable(f"no node serves the action {name}")
        if server.active is not None:
            await server.active.cancel(GoalStatus.PREEMPTED)
        handle = GoalHandle(next(self._ids), goal)
        server.active = handle
        handle._task = asyncio.get_running_loop().create_task(
            server._run(handle), name=f"action:{name}"
        )
        return handle
