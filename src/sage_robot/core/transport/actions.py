"""Bus actions between processes over Zenoh: goal, feedback, result, cancel, preempt.

A process that serves an action offers it with

- a liveliness token ``sage/<robot>/alive/action/<zid>/<name>`` (every process follows these
  tokens (:class:`~.services.Directory`), so ``bus.actions.has(name)`` knows at once whether
  another process serves it, and the token's end says that the server's process is gone:
  Zenoh drops the tokens of a session whose link closed, e.g. after ``kill -9``);
- a queryable ``sage/<robot>/action/<zid>/<name>``, whose queries carry their operation as a
  JSON attachment:

  - ``{"op": "goal", "goal": TOKEN}``, payload the goal's frame (:mod:`.wire`): the goal starts
    on the local server as a local goal would (preempt or queue); the reply is an ack;
  - ``{"op": "poll", "goal": TOKEN, "after": SEQ}``: the feedback after number ``SEQ`` and,
    once the goal ended, its result; held up to :data:`POLL_HOLD_S` while nothing is new;
  - ``{"op": "cancel", "goal": TOKEN, "status": "canceled" | "preempted"}``.

``TOKEN`` is the client's ``<zid>.<goal id>``. The client follows each goal with one task that
polls again as soon as a poll is answered (feedback arrives in order, never after the result,
and none is lost unless more than :data:`~sage_robot.core.actions.FEEDBACK_QUEUE` pile up
between two polls). Every wait is bounded (wall time): a poll that gets no answer while the
server's token is gone, :data:`GONE_MISSES` polls in a row that find no server, or
:data:`SILENT_S` without any answer end the goal as ``ABORTED`` with a reason (and a
best-effort cancel goes to the server). A poll reply is an envelope: ``u32`` header length, a
JSON header ``{"status", "message", "seq", "n", "value"}``, then ``n`` feedback frames and the
result's frame (if ``value``), each as ``u32`` length + frame.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import struct
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass
from typing import Any

import zenoh

from sage_robot.core.actions import FEEDBACK_QUEUE, Accept, ActionResult, GoalHandle, GoalStatus
from sage_robot.core.transport import wire
from sage_robot.core.transport.keys import PREFIX
from sage_robot.core.transport.services import SERVICE_NAME, Directory

GOAL_ACCEPT_S = 5.0  # longest the client waits for the server to take a goal (wall s)
POLL_HOLD_S = 1.0  # the server holds a poll this long while the goal has nothing new (wall s)
REPLY_MARGIN_S = 2.0  # a poll's time limit beyond the hold (a busy server loop) (wall s)
RETRY_S = 0.1  # pause before asking again after a poll that got no answer (wall s)
GONE_MISSES = 5  # polls in a row that find no server: the server is gone
SILENT_S = 10.0  # no answer at all for this long: the server is taken as gone (wall s)
CANCEL_SEND_S = 2.0  # time limit of a cancel's query (wall s)
FINISHED_KEEP_S = 30.0  # the server keeps an ended goal's result this long for its poll (wall s)
CANCEL_STATUSES = {s.value: s for s in (GoalStatus.CANCELED, GoalStatus.PREEMPTED)}
_U32 = struct.Struct("<I")

_log = logging.getLogger("sage.bus.zenoh")


def action_key(robot: str, zid: str, name: str) -> str:
    return f"{PREFIX}/{robot}/action/{zid}/{name.lstrip('/')}"


# ------------------------------------------------------------ envelope
def pack(header: dict[str, Any], frames: list[bytes]) -> bytes:
    head = json.dumps(header, separators=(",", ":")).encode("utf-8")
    parts = [_U32.pack(len(head)), head]
    for frame in frames:
        parts += [_U32.pack(len(frame)), frame]
    return b"".join(parts)


def unpack(data: bytes) -> tuple[dict[str, Any], list[bytes]]:
    """The header and frames of an envelope; :class:`wire.WireError` names what is wrong."""
    try:
        (n,) = _U32.unpack_from(data, 0)
        if 4 + n > len(data):
            raise ValueError("the header runs past the end")
        header = json.loads(data[4 : 4 + n])
        frames, at = [], 4 + n
        while at < len(data):
            (size,) = _U32.unpack_from(data, at)
            if at + 4 + size > len(data):
                raise ValueError("a frame runs past the end")
            frames.append(data[at + 4 : at + 4 + size])
            at += 4 + size
    except (struct.error, ValueError, UnicodeDecodeError) as exc:
        raise wire.WireError(f"bad envelope: {exc}") from None
    if not isinstance(header, dict):
        raise wire.WireError("bad envelope: the header is not an object")
    return header, frames


# ------------------------------------------------------------ the server's side
class ServedGoal(GoalHandle):
    """A goal another process sent: a local goal that keeps its feedback for the polls."""

    def __init__(self, goal_id: int, goal: Any) -> None:
        super().__init__(goal_id, goal)
        self.seq = 0
        self.log: deque[tuple[int, Any]] = deque(maxlen=FEEDBACK_QUEUE)
        self.news = asyncio.Event()
        self.on_finish: Callable[[], None] | None = None

    def _push_feedback(self, msg: Any) -> None:
        if self.done:
            return
        super()._push_feedback(msg)
        self._feedback.clear()  # nobody here reads it: the polls read the log
        self.seq += 1
        self.log.append((self.seq, msg))
        self._poke()

    def _finish(self, result: ActionResult) -> None:
        if self.done:
            return
        super()._finish(result)
        self._poke()
        if self.on_finish is not None:
            self.on_finish()

    def _poke(self) -> None:
        self.news.set()
        self.news = asyncio.Event()


@dataclass
class _Offer:
    accept: Accept
    queryable: Any
    token: Any


# ------------------------------------------------------------ the client's side
class RemoteGoal(GoalHandle):
    """The client's handle of a goal that runs in another process."""

    def __init__(self, goal_id: int, goal: Any, name: str, zid: str, link: ZenohActions) -> None:
        super().__init__(goal_id, goal)
        self.name, self.server_zid, self._link = name, zid, link
        self.token = f"{link.zid}.{goal_id}"
        self.accepted = False

    def request_cancel(self, status: GoalStatus = GoalStatus.CANCELED) -> None:
        if self.done or self.cancel_requested:
            return
        self._cancel_requested, self._cancel_status = True, status
        if self.accepted:
            self._link.send_cancel(self)
        # else: the goal's task sends it once the server took the goal


@dataclass
class _Reply:
    kind: str  # ok | err | none (no server answered) | timeout
    payload: bytes = b""


class ZenohActions:
    """The :class:`~sage_robot.core.actions.RemoteActions` of a Zenoh transport."""

    def __init__(self, session: Any, robot: str, zid: str) -> None:
        self.session, self.robot, self.zid = session, robot, zid
        self._offers: dict[str, _Offer] = {}
        self._served: dict[str, ServedGoal] = {}
        self._sent: dict[str, list[RemoteGoal]] = {}
        self._tasks: set[asyncio.Task[None]] = set()
        self.directory = Directory(session, robot, zid, "action")
        self.stats = {"sent": 0, "served": 0, "server_gone": 0, "unencodable": 0}

    # ------------------------------------------------------------ who serves what
    def server(self, name: str) -> str | None:
        return self.directory.server(name)

    def alive(self, name: str, zid: str) -> bool:
        return self.directory.alive(name, zid)

    def has(self, name: str) -> bool:
        return self.server(name) is not None

    # ------------------------------------------------------------ offering
    def offer(self, name: str, accept: Accept) -> None:
        try:
            loop = asyncio.get_running_loop()
        except RuntimeError:
            loop = None
        if not SERVICE_NAME.match(name) or loop is None:
            why = "its name" if loop is not None else "no running loop"
            _log.warning("action %r stays in this process (%s)", name, why)
            return

        def on_query(query: Any) -> None:  # Zenoh's thread
            self._on_query(loop, name, query)

        queryable = self.session.declare_queryable(
            action_key(self.robot, self.zid, name), on_query, allowed_origin=zenoh.Locality.REMOTE
        )
        token = self.directory.token(name)
        self._offers[name] = _Offer(accept, queryable, token)

    def withdraw(self, name: str) -> None:
        offer = self._offers.pop(name, None)
        if offer is not None:
            for decl in (offer.token, offer.queryable):
                with contextlib.suppress(zenoh.ZError):
                    decl.undeclare()

    def close(self) -> None:
        for name in list(self._offers):
            self.withdraw(name)
        self.directory.close()
        for task in list(self._tasks):
            task.cancel()
        for goals in self._sent.values():
            for goal in goals:
                goal._finish(_aborted("this process's bus closed"))

    def _on_query(self, loop: asyncio.AbstractEventLoop, name: str, query: Any) -> None:  # Zenoh's thread
        try:
            att = json.loads(query.attachment.to_bytes()) if query.attachment is not None else None
            if not isinstance(att, dict) or not isinstance(att.get("goal"), str):
                raise ValueError("no operation")
            payload = query.payload.to_bytes() if query.payload is not None else b""
            future = asyncio.run_coroutine_threadsafe(self._serve(name, att, payload), loop)
        except (ValueError, UnicodeDecodeError, RuntimeError) as exc:  # RuntimeError: the loop closed
            _reply(query, None, f"bad action request: {exc}")
            query.drop()
            return
        future.add_done_callback(lambda f: _answer(query, f))

    async def _serve(self, name: str, att: dict[str, Any], payload: bytes) -> bytes:
        token, op = att["goal"], att.get("op")
        if op == "goal":
            return self._take(name, token, payload)
        if op == "cancel":
            goal = self._served.get(token)
            status = CANCEL_STATUSES.get(str(att.get("status")), GoalStatus.CANCELED)
            if goal is not None:
                goal.request_cancel(status)
            return json.dumps({"known": goal is not None}).encode()
        if op == "poll":
            return await self._poll(token, att.get("after", 0))
        raise ValueError(f"unknown operation {op!r}")

    def _take(self, name: str, token: str, payload: bytes) -> bytes:
        if token not in self._served:
            offer = self._offers.get(name)
            goal = wire.decode(payload)
            handle = offer.accept(goal, ServedGoal) if offer is not None else None
            if not isinstance(handle, ServedGoal):
                raise ValueError(f"no node serves the action {name} here any more")
            self._served[token] = handle
            handle.on_finish = lambda: self._forget_later(token)
            self.stats["served"] += 1
        return b'{"accepted":true}'

    def _forget_later(self, token: str) -> None:
        """An ended goal's result stays for its client's poll a while (even a client that died)."""
        asyncio.get_running_loop().call_later(FINISHED_KEEP_S, self._served.pop, token, None)

    async def _poll(self, token: str, after: Any) -> bytes:
        goal = self._served.get(token)
        if goal is None:
            raise ValueError("this process knows no such goal (its server restarted?)")
        after = after if isinstance(after, int) else 0
        if goal.seq <= after and not goal.done:
            with contextlib.suppress(asyncio.TimeoutError):
                await asyncio.wait_for(goal.news.wait(), POLL_HOLD_S)
        frames, seq = [], after
        for n, msg in list(goal.log):
            if n > after:
                seq = n
                with contextlib.suppress(TypeError):
                    frames.append(wire.encode(msg))
        header: dict[str, Any] = {"status": GoalStatus.EXECUTING.value, "message": "", "seq": seq,
                                  "n": len(frames), "value": False}
        result = goal._result if seq == goal.seq else None  # the result only after all feedback
        if result is not None:
            header.update(status=result.status.value, message=result.message)
            if result.value is not None:
                try:
                    frames.append(wire.encode(result.value))
                    header["value"] = True
                except TypeError as exc:
                    why = f"(the result cannot leave the process: {exc})"
                    header["message"] = f"{result.message} {why}".strip()
        return pack(header, frames)

    # ------------------------------------------------------------ sending
    def active(self, name: str) -> GoalHandle | None:
        for goal in reversed(self._sent.get(name, [])):
            if not goal.done:
                return goal
        return None

    def send_goal(self, name: str, goal_id: int, goal: Any) -> GoalHandle:
        zid = self.server(name)
        handle = RemoteGoal(goal_id, goal, name, zid or "", self)
        sent = [g for g in self._sent.get(name, []) if not g.done]
        self._sent[name] = [*sent, handle]
        self.stats["sent"] += 1
        self._spawn(self._follow(handle), f"goal:{name}")
        return handle

    def send_cancel(self, goal: RemoteGoal) -> None:
        self._spawn(self._cancel(goal), f"cancel:{goal.name}")

    def _spawn(self, coro: Any, name: str) -> None:
        task = asyncio.get_running_loop().create_task(coro, name=name)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    async def _cancel(self, goal: RemoteGoal) -> None:
        att = {"op": "cancel", "goal": goal.token, "status": goal._cancel_status.value}
        reply = await self._query(goal, att, None, CANCEL_SEND_S)
        if reply.kind != "ok":
            _log.warning("the cancel of %s goal %d got no answer (%s)", goal.name, goal.goal_id, reply.kind)

    async def _follow(self, goal: RemoteGoal) -> None:
        """Send the goal, then poll until it ends (every step bounded)."""
        try:
            frame = wire.encode(goal.goal)
        except TypeError as exc:
            self.stats["unencodable"] += 1
            goal._finish(_aborted(f"the goal cannot leave the process: {exc}"))
            return
        reply = await self._query(goal, {"op": "goal", "goal": goal.token}, frame, GOAL_ACCEPT_S)
        if reply.kind != "ok":
            goal._finish(_aborted(self._why(goal, reply, "take the goal", silent_s=GOAL_ACCEPT_S)))
            if reply.kind == "timeout":  # it may have arrived late: it must not run unwatched
                self.send_cancel_anyway(goal)
            return
        goal.accepted = True
        if goal.cancel_requested:
            self.send_cancel(goal)
        await self._poll_until_done(goal)

    async def _poll_until_done(self, goal: RemoteGoal) -> None:
        loop = asyncio.get_running_loop()
        after, misses, heard = 0, 0, loop.time()
        while not goal.done:
            att = {"op": "poll", "goal": goal.token, "after": after}
            reply = await self._query(goal, att, None, POLL_HOLD_S + REPLY_MARGIN_S)
            if reply.kind == "ok":
                misses, heard = 0, loop.time()
                after = self._take_news(goal, reply.payload, after)
                continue
            misses += 1
            gone = not self.alive(goal.name, goal.server_zid) or misses >= GONE_MISSES
            if reply.kind == "err" or gone or loop.time() - heard >= SILENT_S:
                if reply.kind != "err":
                    self.stats["server_gone"] += 1
                goal._finish(_aborted(self._why(goal, reply, "finish the goal", gone)))
                if not gone:
                    self.send_cancel_anyway(goal)
                return
            await asyncio.sleep(RETRY_S)

    def send_cancel_anyway(self, goal: RemoteGoal) -> None:
        """A goal given up on here is asked to stop there too (best effort)."""
        goal._cancel_status = GoalStatus.CANCELED
        self.send_cancel(goal)

    def _take_news(self, goal: RemoteGoal, payload: bytes, after: int) -> int:
        try:
            header, frames = unpack(payload)
            feedback = [wire.decode(f) for f in frames[: int(header["n"])]]
            status = GoalStatus(header["status"])
            value = wire.decode(frames[-1]) if header.get("value") else None
        except (wire.WireError, KeyError, ValueError, TypeError, IndexError) as exc:
            goal._finish(_aborted(f"the {goal.name} server's reply was not understood: {exc}"))
            return after
        for msg in feedback:
            goal._push_feedback(msg)
        if status.done:
            goal._finish(ActionResult(status, value, str(header.get("message", ""))))
        seq = header.get("seq", after)
        return seq if isinstance(seq, int) else after

    def _why(
        self, goal: RemoteGoal, reply: _Reply, what: str, gone: bool = False, silent_s: float = SILENT_S
    ) -> str:
        if reply.kind == "err":
            return f"the {goal.name} server could not {what}: {reply.payload.decode('utf-8', 'replace')}"
        if gone or reply.kind == "none":
            return f"the process serving {goal.name} went away before it could {what}"
        return f"the process serving {goal.name} did not answer (to {what}) for {silent_s:g} s"

    async def _query(
        self, goal: RemoteGoal, att: dict[str, Any], payload: bytes | None, limit: float
    ) -> _Reply:
        """One query to the goal's server, bounded by ``limit`` (wall s)."""
        if not goal.server_zid:
            return _Reply("none")
        loop = asyncio.get_running_loop()
        done: asyncio.Future[_Reply] = loop.create_future()
        started = loop.time()

        def settle(reply: _Reply) -> None:  # on the loop
            if not done.done():
                if reply.kind == "none" and loop.time() - started >= limit - 0.05:
                    reply = _Reply("timeout")
                done.set_result(reply)

        def on_reply(r: Any) -> None:  # Zenoh's thread
            ok = r.ok is not None
            data = (r.ok if ok else r.err).payload.to_bytes()
            _call_soon(loop, settle, _Reply("ok" if ok else "err", data))

        def on_end() -> None:  # Zenoh's thread: every reply is in (or none came)
            _call_soon(loop, settle, _Reply("none"))

        try:
            self.session.get(
                action_key(self.robot, goal.server_zid, goal.name),
                zenoh.handlers.Callback(on_reply, on_end),
                payload=payload,
                attachment=json.dumps(att),
                timeout=limit,
            )
        except zenoh.ZError as exc:  # the session closed
            return _Reply("err", str(exc).encode())
        try:
            return await asyncio.wait_for(done, limit + 1.0)
        except asyncio.TimeoutError:
            return _Reply("timeout")


def _aborted(message: str) -> ActionResult:
    return ActionResult(GoalStatus.ABORTED, None, message)


def _answer(query: Any, future: Future[bytes]) -> None:
    """Reply to an action query with its outcome (on the serving loop's thread)."""
    try:
        exc = future.exception() if not future.cancelled() else RuntimeError("cancelled")
        if exc is not None:
            _reply(query, None, str(exc) if isinstance(exc, (ValueError, wire.WireError)) else repr(exc))
        else:
            _reply(query, future.result(), "")
    finally:
        query.drop()


def _reply(query: Any, payload: bytes | None, error: str) -> None:
    with contextlib.suppress(zenoh.ZError):
        if payload is None:
            query.reply_err(error)
        else:
            query.reply(str(query.key_expr), payload)


def _call_soon(loop: asyncio.AbstractEventLoop, fn: Callable[..., None], *args: Any) -> None:
    with contextlib.suppress(RuntimeError):  # the loop closed: nobody waits any more
        loop.call_soon_threadsafe(fn, *args)
