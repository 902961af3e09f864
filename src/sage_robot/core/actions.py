"""Actions: long-running goals with a feedback stream, cancel and a result (ROS 2 semantics).

A server is ``async def handler(goal, ctx) -> result``. It sends feedback with
``ctx.feedback(msg)``; a cancel arrives as ``asyncio.CancelledError`` inside the handler
(clean up in ``finally``); raising :class:`ActionAborted` ends the goal as aborted with a
reason a person understands.

One goal runs at a time per server, chosen by the server's policy:

- ``preempt`` (the default, as for navigation): a new goal preempts the running one, whose
  client sees ``PREEMPTED``;
- ``queue`` (as for conversation): goals run one after another in arrival order; at most
  ``max_queue`` wait, a goal beyond that ends at once as ``ABORTED`` ("busy").

Nothing here can wedge (safety depends on it: the e-stop and the pages cancel goals):

- :meth:`ActionRegistry.send_goal` never waits for another goal. The previous goal is asked
  to stop and the new one starts its handler only once every earlier goal of the server
  has wound down (at most :data:`PREEMPT_WAIT_S`; after that the new goal is aborted and
  says why), so two handlers of one server never overlap.
- Every goal ends with a result, whenever it is cancelled: before its handler ran, while it
  waited for its turn, inside its handler, or by a server going away (``unserve``).
- Every client wait is bounded: :meth:`GoalHandle.cancel` gives up after
  :data:`CANCEL_WAIT_S` (raising :class:`GoalTimeout`; the cancel stays requested), and
  :meth:`GoalHandle.result` takes a timeout. :meth:`GoalHandle.request_cancel` does not
  wait at all (for the safety paths).

Across processes (a networked transport's :class:`RemoteActions`, e.g. Zenoh's
:mod:`sage_robot.core.transport.actions`): a server is also offered to other processes, and
a goal for an action no local node serves goes to the process that serves it. The client
gets the same :class:`GoalHandle` API (feedback, result, cancel); a server process that dies
ends the goal as ``ABORTED`` with a reason, within a bounded time. A local server always
wins, so a single process behaves exactly as before.
"""

from __future__ import annotations

import asyncio
import functools
import itertools
import logging
from collections import deque
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from enum import Enum
from typing import TYPE_CHECKING, Any, Literal, Protocol

from sage_robot.core.errors import SageError, ServiceUnavailable

if TYPE_CHECKING:
    from sage_robot.core.bus import Bus

FEEDBACK_QUEUE = 32  # feedback messages kept per goal before the oldest is dropped
CANCEL_WAIT_S = 5.0  # longest a client waits for a cancelled goal to wind down (wall s)
PREEMPT_WAIT_S = 10.0  # longest a new goal waits for earlier goals to wind down (wall s)
DEFAULT_MAX_QUEUE = 8  # goals that may wait behind the running one on a "queue" server

Policy = Literal["preempt", "queue"]

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


class GoalTimeout(SageError, TimeoutError):
    """A bounded wait on a goal ran out (the goal goes on; a cancel stays requested)."""


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
        self._cancel_requested = False
        self.last_feedback: Any = None

    def _push_feedback(self, msg: Any) -> None:
        if self._result is not None:
            return  # a handler that outlived its goal (it ignored the cancel): not news
        self._feedback.append(msg)
        self.last_feedback = msg
        self._changed.set()

    def _finish(self, result: ActionResult) -> None:
        if self._result is not None:
            return  # the first ending stands
        self._result = result
        self.status = result.status
        self._changed.set()

    @property
    def done(self) -> bool:
        return self._result is not None

    @property
    def cancel_requested(self) -> bool:
        return self._cancel_requested

    async def result(self, timeout: float | None = None) -> ActionResult:
        """The goal's result; raises :class:`GoalTimeout` after ``timeout`` wall seconds."""
        if timeout is None:
            return await self._wait_result()
        try:
            return await asyncio.wait_for(self._wait_result(), timeout)
        except asyncio.TimeoutError:
            raise GoalTimeout(f"goal {self.goal_id} did not end within {timeout:g} s") from None

    async def _wait_result(self) -> ActionResult:
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

    def request_cancel(self, status: GoalStatus = GoalStatus.CANCELED) -> None:
        """Ask the server to stop this goal; returns at once (the result comes later)."""
        if self._result is not None or self._cancel_requested:
            return
        self._cancel_requested, self._cancel_status = True, status
        if self._task is not None:
            self._task.cancel()

    async def cancel(
        self, status: GoalStatus = GoalStatus.CANCELED, timeout: float = CANCEL_WAIT_S
    ) -> ActionResult:
        """Ask the server to stop this goal and wait (at most ``timeout`` s) for it to wind down."""
        self.request_cancel(status)
        return await self.result(timeout)


Handler = Callable[[Any, GoalContext], Awaitable[Any]]
Accept = Callable[[Any, "type[GoalHandle]"], "GoalHandle | None"]  # (goal, handle class) -> started goal


class RemoteActions(Protocol):
    """Actions beyond this process, as a networked transport offers them
    (:meth:`~sage_robot.core.bus.Transport.remote_actions`)."""

    def offer(self, name: str, accept: Accept) -> None:
        """Other processes may send goals to the local server ``name``; ``accept`` starts one
        on it (on the bus's loop) and returns its handle, or None when it is no longer served."""

    def withdraw(self, name: str) -> None:
        """The local server ``name`` is gone."""

    def has(self, name: str) -> bool:
        """Whether another process serves ``name`` now."""

    def send_goal(self, name: str, goal_id: int, goal: Any) -> GoalHandle:
        """Start ``goal`` on another process's server (never waits); the handle follows it."""

    def active(self, name: str) -> GoalHandle | None:
        """The latest goal this process sent to another's ``name`` that has not ended."""


class ActionServer:
    def __init__(
        self, name: str, handler: Handler, policy: Policy = "preempt", max_queue: int = DEFAULT_MAX_QUEUE
    ) -> None:
        if policy not in ("preempt", "queue"):
            raise ValueError(f"action {name}: unknown policy {policy!r} (preempt or queue)")
        self.name, self.handler, self.policy, self.max_queue = name, handler, policy, max_queue
        self.active: GoalHandle | None = None  # the goal that runs, or is next to run
        self.waiting: deque[GoalHandle] = deque()  # "queue" policy: goals behind the active one
        self._live: list[GoalHandle] = []  # goals whose task has not ended, oldest first
        self.counts = {s: 0 for s in GoalStatus}

    def start(self, handle: GoalHandle) -> None:
        """Take a new goal according to the policy (never waits)."""
        if self.policy == "queue" and self.active is not None:
            if len(self.waiting) >= self.max_queue:
                self._end(handle, ActionResult(GoalStatus.ABORTED, None, f"{self.name} is busy; try again"))
                return
            self.waiting.append(handle)
            self._launch(handle)
            return
        if self.active is not None:
            self.active.request_cancel(GoalStatus.PREEMPTED)
        self.active = handle
        self._launch(handle)

    def stop_all(self) -> None:
        """The server goes away: every goal it holds ends (cancelled)."""
        for handle in list(self._live):
            handle.request_cancel()

    def _launch(self, handle: GoalHandle) -> None:
        earlier = [h._task for h in self._live if h._task is not None]
        self._live.append(handle)
        task = asyncio.get_running_loop().create_task(self._run(handle, earlier), name=f"action:{self.name}")
        handle._task = task
        task.add_done_callback(lambda _t: self._ended(handle))

    async def _run(self, handle: GoalHandle, earlier: list[asyncio.Task[None]]) -> None:
        try:
            if not await self._wait_turn(handle, earlier):
                return
            value = await self.handler(handle.goal, GoalContext(handle))
            result = ActionResult(GoalStatus.SUCCEEDED, value)
        except asyncio.CancelledError:
            result = ActionResult(handle._cancel_status, None, handle._cancel_status.value)
        except ActionAborted as exc:
            result = ActionResult(GoalStatus.ABORTED, None, str(exc))
        except Exception as exc:
            _log.exception("action %s failed", self.name)
            result = ActionResult(GoalStatus.ABORTED, None, f"internal error: {exc}")
        self._end(handle, result)

    async def _wait_turn(self, handle: GoalHandle, earlier: list[asyncio.Task[None]]) -> bool:
        """Wait until every earlier goal has ended (bounded); False when this goal ended instead."""
        pending = [t for t in earlier if not t.done()]
        if self.policy == "queue":
            while pending:  # wait as long as the queue takes, one goal at a time
                await asyncio.wait(pending)
                pending = [t for t in earlier if not t.done()]
            if self.waiting and self.waiting[0] is handle:
                self.waiting.popleft()
            self.active = handle
            return True
        if pending:
            _, still = await asyncio.wait(pending, timeout=PREEMPT_WAIT_S)
            if still:
                _log.error("action %s: the previous goal ignored its cancel", self.name)
                why = f"the previous {self.name} goal did not stop within {PREEMPT_WAIT_S:g} s"
                self._end(handle, ActionResult(GoalStatus.ABORTED, None, why))
                return False
        return True

    def _end(self, handle: GoalHandle, result: ActionResult) -> None:
        if handle.done:
            return
        self.counts[result.status] += 1
        handle._finish(result)
        if handle in self.waiting:
            self.waiting.remove(handle)
        if self.active is handle:
            self.active = self.waiting[0] if self.waiting else None

    def _ended(self, handle: GoalHandle) -> None:
        """The goal's task is over, however it ended: it must have a result."""
        if handle in self._live:
            self._live.remove(handle)
        if handle in self.waiting:
            self.waiting.remove(handle)
        status = handle._cancel_status
        self._end(handle, ActionResult(status, None, status.value))  # cancelled before it ran


class ActionRegistry:
    """The bus's action servers (``bus.actions``)."""

    def __init__(self, bus: Bus) -> None:
        self._bus = bus
        self._servers: dict[str, ActionServer] = {}
        self._ids = itertools.count(1)
        self._remote: RemoteActions | None = bus.transport.remote_actions()

    def serve(
        self, name: str, handler: Handler, policy: Policy = "preempt", max_queue: int = DEFAULT_MAX_QUEUE
    ) -> ActionServer:
        if name in self._servers:
            raise ValueError(f"action {name} is already served")
        server = self._servers[name] = ActionServer(name, handler, policy, max_queue)
        if self._remote is not None:
            self._remote.offer(name, functools.partial(self._accept, name))
        return server

    def _accept(self, name: str, goal: Any, cls: type[GoalHandle]) -> GoalHandle | None:
        """A goal from another process: started on the local server like a local one."""
        server = self._servers.get(name)
        if server is None:
            return None
        handle = cls(next(self._ids), goal)
        server.start(handle)
        return handle

    def unserve(self, name: str) -> ActionServer | None:
        """Stop serving ``name`` (its goals end, cancelled); the server that was removed."""
        server = self._servers.pop(name, None)
        if server is not None:
            server.stop_all()
            if self._remote is not None:
                self._remote.withdraw(name)
        return server

    def has(self, name: str) -> bool:
        """Whether a node serves ``name``, in this process or (networked) in another."""
        return name in self._servers or (self._remote is not None and self._remote.has(name))

    def active(self, name: str) -> GoalHandle | None:
        """The local server's running goal; without one, the latest unfinished goal this
        process sent to another process's server."""
        server = self._servers.get(name)
        if server is not None:
            return server.active
        return self._remote.active(name) if self._remote is not None else None

    async def send_goal(self, name: str, goal: Any) -> GoalHandle:
        """Start a goal (never waits for another goal); a running goal on a ``preempt``
        server is asked to stop first and the new handler runs once it has."""
        server = self._servers.get(name)
        if server is None:
            if self._remote is not None and self._remote.has(name):
                return self._remote.send_goal(name, next(self._ids), goal)
            raise ServiceUnavailable(f"no node serves the action {name}")
        handle = GoalHandle(next(self._ids), goal)
        server.start(handle)
        return handle
