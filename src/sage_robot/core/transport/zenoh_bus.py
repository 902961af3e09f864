"""The bus over Zenoh: :class:`ZenohTransport`.

Inside the process nothing changes: the bus hands local subscribers the object itself. Each
publication is also put on ``sage/<robot>/topic/<name>`` — encoded (:mod:`.wire`) only while
some other process subscribes to it, so an unwatched camera costs nothing. A process
subscribes only to the topics its nodes read (:meth:`ZenohTransport.want`: a subscription,
a latched declaration, a ``latest()``), or to all of them while something holds
:meth:`ZenohTransport.want_all` (a recorder, a Foxglove viewer): a topic nobody reads in
another process is never encoded, sent or decoded. Wanting a latched topic also asks the
other processes for its last value (``last/<name>``), so a process that starts late or
restarts sees the e-stop, the map and the health at once. Remote publications arrive on
Zenoh's thread, are decoded there and handed to the bus, which delivers them on its loop.
Publishers send only to remote subscribers and subscribers take only remote samples
(Zenoh's locality), so a process never hears itself.

Queryables answer tools without a subscription: ``info/<zid>`` (topics, types, counts),
``last/<name>`` (the last message published here) and ``pub/<name>`` (an operator's
publication, checked against the operator password; `sage topic pub`).
"""

from __future__ import annotations

import contextlib
import dataclasses
import hmac
import json
import logging
import os
import threading
from collections.abc import Callable
from typing import Any

import numpy as np
import zenoh

from sage_robot.core.bus import Transport
from sage_robot.core.clock import TIME_EPS_S
from sage_robot.core.config.bus import BusSettings
from sage_robot.core.transport import wire
from sage_robot.core.transport.actions import ZenohActions
from sage_robot.core.transport.keys import (
    TOPIC_NAME,
    kind_key,
    open_session,
    session_config,
    topic_key,
    topic_of,
)
from sage_robot.core.transport.services import Call, ZenohServices

_log = logging.getLogger("sage.bus.zenoh")

LAST_TIMEOUT_S = 2.0  # how long a late joiner's question for a latched topic's last value stays open


def repeats(msg: Any, last: Any, within_s: float) -> bool:
    """``msg`` equals ``last`` in every field but ``stamp``, and is stamped less than
    ``within_s`` after it. Messages without a stamp, or with an array, never repeat."""
    if type(msg) is not type(last) or not dataclasses.is_dataclass(msg):
        return False
    stamp, last_stamp = getattr(msg, "stamp", None), getattr(last, "stamp", None)
    if not isinstance(stamp, float) or not isinstance(last_stamp, float):
        return False
    if stamp - last_stamp >= within_s - TIME_EPS_S:
        return False
    for f in dataclasses.fields(msg):
        if f.name == "stamp":
            continue
        a, b = getattr(msg, f.name), getattr(last, f.name)
        if isinstance(a, np.ndarray) or isinstance(b, np.ndarray) or a != b:
            return False
    return True


def _direct(callback: Callable[[Any], None]) -> Any:
    """Run ``callback`` on Zenoh's network thread rather than on a Python thread of its own
    (zenoh-python's default): one thread hand-off less per sample. The callbacks only decode
    and queue the message for the bus's loop."""
    return zenoh.handlers.Callback(callback, indirect=False)


class ZenohTransport(Transport):
    """Publications go to Zenoh as well; other processes' come back to the bus."""

    def __init__(self, settings: BusSettings, operator_password: Callable[[], str] | None = None) -> None:
        self.robot = settings.robot_id
        z = settings.zenoh
        self.session = open_session(session_config(z, None, None), "bus")
        self.zid = str(self.session.zid())
        self.services = ZenohServices(self.session, self.robot)
        self.actions = ZenohActions(self.session, self.robot, self.zid)
        self._operator_password = operator_password
        self._deliver: Callable[[str, Any], None] | None = None
        self._publishers: dict[str, Any] = {}
        self._matched: dict[str, bool] = {}
        self._repeat_every = dict(z.repeat_every_s)  # topic -> s between unchanged messages sent
        self._sent_last: dict[str, Any] = {}  # of those topics: the last message sent
        self.held_back = 0  # unchanged messages not sent (repeat_every_s)
        self._local_only: set[str] = set()  # topics whose messages cannot be encoded
        self._warned: set[str] = set()  # topics a bad frame came in on
        self._last: dict[str, Any] = {}
        self._counts: dict[str, int] = {}
        self._received: dict[str, int] = {}  # topic -> messages from other processes
        self._declared: list[Any] = []
        self._wanted: dict[str, Any] = {}  # topic -> its Zenoh subscriber (while read here)
        self._fresh: set[str] = set()  # wanted topics a live sample or a last value came in on
        self._everything: Any = None  # the sage/<robot>/topic/** subscriber while want_all holds
        self._holds = 0
        self._lock = threading.Lock()  # declarations vs close
        self.sent = 0
        self.received = 0
        self.rejected = 0  # frames that did not decode, refused publications
        self.closed = False

    # ------------------------------------------------------------ Transport
    def attach(self, deliver: Callable[[str, Any], None]) -> None:
        self._deliver = deliver
        remote = zenoh.Locality.REMOTE
        s = self.session
        self._declared += [
            s.declare_queryable(kind_key(self.robot, "info", self.zid), self._on_info, allowed_origin=remote),
            s.declare_queryable(kind_key(self.robot, "last"), self._on_last, allowed_origin=remote),
            s.declare_queryable(kind_key(self.robot, "pub"), self._on_pub, allowed_origin=remote),
        ]

    def send(self, topic: str, msg: Any) -> None:
        if self.closed or topic in self._local_only:
            return
        self._last[topic] = msg
        self._counts[topic] = self._counts.get(topic, 0) + 1
        pub = self._publishers.get(topic)
        if pub is None:
            pub = self._declare_publisher(topic)
            if pub is None:
                return
        if not self._matched.get(topic):
            return
        if topic in self._repeat_every and self._hold_back(topic, msg):
            return
        try:
            frame = wire.encode(msg)
        except TypeError as exc:
            self._local_only.add(topic)
            _log.warning("topic %s stays in this process: %s", topic, exc)
            return
        pub.put(frame)
        self.sent += 1

    def want(self, topic: str, latched: bool) -> None:
        if not TOPIC_NAME.match(topic):
            return  # it cannot travel: it stays in this process (see _declare_publisher)
        with self._lock:
            if self.closed or topic in self._wanted:
                return
            key = topic_key(self.robot, topic)
            on_sample, remote = _direct(self._on_sample), zenoh.Locality.REMOTE
            self._wanted[topic] = self.session.declare_subscriber(key, on_sample, allowed_origin=remote)
            if latched:  # a late joiner: the other processes' last value
                self.session.get(
                    kind_key(self.robot, "last", topic[1:]), self._on_last_reply,
                    allowed_destination=zenoh.Locality.REMOTE, timeout=LAST_TIMEOUT_S,
                )  # fmt: skip

    def unwant(self, topic: str) -> None:
        with self._lock:
            sub = self._wanted.pop(topic, None)
            self._fresh.discard(topic)
            if sub is not None and not self.closed:
                with contextlib.suppress(zenoh.ZError):
                    sub.undeclare()

    def want_all(self) -> Callable[[], None]:
        with self._lock:
            if self.closed:
                return lambda: None
            self._holds += 1
            if self._everything is None:
                self._everything = self.session.declare_subscriber(
                    kind_key(self.robot, "topic"), _direct(self._on_any_sample),
                    allowed_origin=zenoh.Locality.REMOTE,
                )
        released = False

        def release() -> None:
            nonlocal released
            with self._lock:
                if released or self.closed:
                    return
                released = True
                self._holds -= 1
                if self._holds == 0 and self._everything is not None:
                    with contextlib.suppress(zenoh.ZError):
                        self._everything.undeclare()
                    self._everything = None

        return release

    def offer(self, name: str, call: Call) -> None:
        self.services.offer(name, call)

    def withdraw(self, name: str) -> None:
        self.services.withdraw(name)

    async def call(self, name: str, request: Any, timeout: float | None) -> Any:
        return await self.services.call(name, request, timeout)

    def has_service(self, name: str) -> bool:
        return self.services.has(name)

    def remote_actions(self) -> ZenohActions:
        return self.actions

    def matched(self, topic: str) -> bool:
        """Whether another process subscribes to ``topic`` now (the first question declares the
        topic's publisher, whose matching status says it)."""
        if topic not in self._publishers and topic not in self._local_only and not self.closed:
            self._declare_publisher(topic)
        return bool(self._matched.get(topic))

    def close(self) -> None:
        with self._lock:
            if self.closed:
                return
            self.closed = True
        self.services.close()
        self.actions.close()
        everything = [self._everything] if self._everything is not None else []
        for decl in [*self._declared, *everything, *self._wanted.values(), *self._publishers.values()]:
            with contextlib.suppress(zenoh.ZError):  # the session closed at exit already
                decl.undeclare()
        self._declared.clear()
        self._wanted.clear()
        self._publishers.clear()
        self.session.close()

    # ------------------------------------------------------------ publishing
    def _declare_publisher(self, topic: str) -> Any:
        if not TOPIC_NAME.match(topic):
            self._local_only.add(topic)
            _log.warning("topic %r stays in this process: not a name Zenoh can carry", topic)
            return None
        with self._lock:
            if self.closed:
                return None
            pub = self.session.declare_publisher(
                topic_key(self.robot, topic), express=True, allowed_destination=zenoh.Locality.REMOTE
            )
            self._matched[topic] = pub.matching_status.matching

            def on_match(status: Any) -> None:
                self._matched[topic] = status.matching

            self._declared.append(pub.declare_matching_listener(on_match))
            self._publishers[topic] = pub
        return pub

    def _hold_back(self, topic: str, msg: Any) -> bool:
        """Whether ``msg`` repeats the last message sent on ``topic`` (all but its stamp) within
        the topic's ``repeat_every_s``; if not, it becomes the last one sent."""
        last = self._sent_last.get(topic)
        if last is not None and repeats(msg, last, self._repeat_every[topic]):
            self.held_back += 1
            return True
        self._sent_last[topic] = msg
        return False

    # ------------------------------------------------------------ from Zenoh's threads
    def _on_any_sample(self, sample: Any) -> None:
        topic = topic_of(self.robot, "topic", str(sample.key_expr))
        if topic is not None and topic not in self._wanted:  # a wanted one comes on its own
            self._take(topic, sample.payload)

    def _on_sample(self, sample: Any) -> None:
        topic = topic_of(self.robot, "topic", str(sample.key_expr))
        if topic is not None:
            self._fresh.add(topic)
            self._take(topic, sample.payload)

    def _on_last_reply(self, reply: Any) -> None:
        if reply.ok is None:
            return
        topic = topic_of(self.robot, "last", str(reply.ok.key_expr))
        if topic is None or topic in self._fresh:  # a live one (or another process's last) came first
            return
        self._fresh.add(topic)
        self._take(topic, reply.ok.payload)

    def _take(self, topic: str, payload: Any) -> None:
        if self._deliver is None:
            return
        try:
            msg = wire.decode(payload.to_bytes())
        except wire.WireError as exc:
            self.rejected += 1
            if topic not in self._warned:  # once per topic: a broken peer must not flood the log
                self._warned.add(topic)
                _log.warning("bad frame on %s dropped (counted from now on): %s", topic, exc)
            return
        self.received += 1
        self._received[topic] = self._received.get(topic, 0) + 1
        self._deliver(topic, msg)

    def _on_info(self, query: Any) -> None:
        counts = dict(self._counts)
        types = {t: type(m).__name__ for t, m in list(self._last.items())}
        topics = {t: {"type": types.get(t, "?"), "published": n} for t, n in sorted(counts.items())}
        body = {"zid": self.zid, "pid": os.getpid(), "robot": self.robot, "topics": topics,
                "received": dict(sorted(self._received.items()))}  # fmt: skip
        query.reply(kind_key(self.robot, "info", self.zid), json.dumps(body))

    def _on_last(self, query: Any) -> None:
        wanted = query.key_expr
        for topic, msg in list(self._last.items()):
            key = kind_key(self.robot, "last", topic[1:])
            if topic in self._local_only or not wanted.intersects(zenoh.KeyExpr(key)):
                continue
            try:
                query.reply(key, wire.encode(msg))
            except TypeError:  # not a wire message: it never leaves the process
                continue

    def _on_pub(self, query: Any) -> None:
        topic = topic_of(self.robot, "pub", str(query.key_expr))
        refusal = self._check_pub(query, topic)
        if refusal:
            self.rejected += 1
            query.reply_err(refusal)
            return
        try:
            msg = wire.decode(query.payload.to_bytes())
        except wire.WireError as exc:
            self.rejected += 1
            query.reply_err(f"bad message: {exc}")
            return
        if topic is None or self._deliver is None:  # _check_pub refused both already
            return
        self._deliver(topic, msg)
        self._last[topic] = msg
        query.reply(str(query.key_expr), json.dumps({"published": topic, "type": type(msg).__name__}))

    def _check_pub(self, query: Any, topic: str | None) -> str:
        """Why an operator publication is refused ('' when it is not)."""
        if topic is None:
            return "bad topic name"
        if self._operator_password is None or self._deliver is None:
            return "this robot takes no publications from tools"
        given = query.attachment.to_bytes() if query.attachment is not None else b""
        expected = self._operator_password().encode("utf-8")
        if not hmac.compare_digest(given, expected):
            _log.warning("publication on %s refused: wrong operator password", topic)
            return "wrong operator password"
        if query.payload is None:
            return "no message"
        return ""
