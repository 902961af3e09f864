"""Attach to a running robot over Zenoh without starting one (`sage topic`, `sage status`).

A :class:`RemoteRobot` is a Zenoh peer that listens nowhere and connects to the robot's
endpoints. Every wait is bounded by ``timeout_s``; :meth:`close` (or ``with``) ends the
session.
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Callable
from typing import Any

from sage_robot.core.bus import Transport
from sage_robot.core.config.bus import BusSettings
from sage_robot.core.errors import SageError
from sage_robot.core.transport import wire
from sage_robot.core.transport.keys import (
    check_topic,
    kind_key,
    open_session,
    session_config,
    tool_endpoints,
    topic_key,
    topic_of,
)

POLL_S = 0.01  # how often a bounded wait looks again

_log = logging.getLogger("sage.bus.zenoh")


class RobotUnreachable(SageError):
    """No robot process answered on the endpoints within the timeout."""


class RemoteRobot:
    """A tool's link to a running robot."""

    def __init__(
        self, settings: BusSettings, connect: list[str] | None = None, timeout_s: float | None = None
    ) -> None:
        self.robot = settings.robot_id
        self.timeout_s = settings.zenoh.open_timeout_s if timeout_s is None else timeout_s
        self.endpoints = connect or tool_endpoints(settings.zenoh)
        cfg = session_config(settings.zenoh, [], self.endpoints)
        self.session = open_session(cfg, "sage")
        self._declared: list[Any] = []

    def __enter__(self) -> RemoteRobot:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        for decl in self._declared:
            decl.undeclare()
        self._declared.clear()
        if not self.session.is_closed():
            self.session.close()

    def wait_connected(self) -> bool:
        """True once some peer or router is connected (at most ``timeout_s``)."""
        deadline = time.monotonic() + self.timeout_s
        while True:
            info = self.session.info
            if info.peers_zid() or info.routers_zid():
                return True
            if time.monotonic() >= deadline:
                return False
            time.sleep(POLL_S)

    def require_connected(self) -> None:
        if not self.wait_connected():
            raise RobotUnreachable(
                f"no robot answers on {', '.join(self.endpoints) or '(no endpoints)'} within "
                f"{self.timeout_s:g} s; is it running with bus.transport: zenoh?"
            )

    # ------------------------------------------------------------ queries
    def _get(self, key: str, payload: bytes | None = None, attachment: str | None = None) -> list[Any]:
        replies = self.session.get(key, payload=payload, attachment=attachment, timeout=self.timeout_s)
        return list(replies)

    def processes(self) -> list[dict[str, Any]]:
        """Each robot process's topics: ``[{"zid", "pid", "topics": {name: {type, published}}}]``.
        Asked again until one answers or the time is up (declarations travel after connecting)."""
        deadline = time.monotonic() + self.timeout_s
        while True:
            out = []
            for reply in self._get(kind_key(self.robot, "info", "*")):
                if reply.ok is not None:
                    out.append(json.loads(reply.ok.payload.to_bytes()))
            if out or time.monotonic() >= deadline:
                return out
            time.sleep(POLL_S * 10)

    def topics(self) -> dict[str, dict[str, Any]]:
        """Every published topic: name → {"type", "published"} (summed over processes)."""
        merged: dict[str, dict[str, Any]] = {}
        for proc in self.processes():
            for name, info in proc.get("topics", {}).items():
                entry = merged.setdefault(name, {"type": info.get("type", "?"), "published": 0})
                entry["published"] += int(info.get("published", 0))
        return dict(sorted(merged.items()))

    def last(self, topic: str) -> Any:
        """The last message published on ``topic`` by a robot process, or None."""
        key = kind_key(self.robot, "last", check_topic(topic)[1:])
        for reply in self._get(key):
            if reply.ok is not None:
                return wire.decode(reply.ok.payload.to_bytes())
        return None

    def publish(self, topic: str, msg: Any, password: str) -> int:
        """Publish ``msg`` on the robot's bus as the operator. Returns how many robot processes
        took it; a refusal raises :class:`SageError` with the robot's reason."""
        key = kind_key(self.robot, "pub", check_topic(topic)[1:])
        taken, errors = 0, []
        for reply in self._get(key, wire.encode(msg), password):
            if reply.ok is not None:
                taken += 1
            else:
                errors.append(reply.err.payload.to_string())
        if errors:
            raise SageError(f"the robot refused the publication on {topic}: {errors[0]}")
        if not taken:
            raise RobotUnreachable(
                f"no robot process took the publication on {topic} within {self.timeout_s:g} s"
            )
        return taken

    # ------------------------------------------------------------ streams
    def subscribe(
        self, topic: str, on_msg: Callable[[str, Any], None], on_error: Callable[[str], None]
    ) -> None:
        """Call ``on_msg(topic, msg)`` on Zenoh's thread for each message on ``topic``; a frame
        that does not decode goes to ``on_error``."""
        key = topic_key(self.robot, topic)

        def handler(sample: Any) -> None:
            name = topic_of(self.robot, "topic", str(sample.key_expr)) or str(sample.key_expr)
            try:
                msg = wire.decode(sample.payload.to_bytes())
            except wire.WireError as exc:
                on_error(f"{name}: {exc}")
                return
            on_msg(name, msg)

        self._declared.append(self.session.declare_subscriber(key, handler))

    def publisher(self, topic: str) -> RawPublisher:
        """A plain publisher on ``topic`` (no password: the Zenoh network is the boundary). For
        benchmarks and tests of multi-process robots; `sage topic pub` uses :meth:`publish`."""
        pub = self.session.declare_publisher(topic_key(self.robot, topic), express=True)
        self._declared.append(pub)
        return RawPublisher(pub, self.timeout_s)


class RawPublisher:
    def __init__(self, pub: Any, timeout_s: float) -> None:
        self._pub, self.timeout_s = pub, timeout_s

    def put(self, msg: Any) -> None:
        self._pub.put(wire.encode(msg))

    def wait_matched(self) -> bool:
        """True once some subscriber listens (at most ``timeout_s``)."""
        deadline = time.monotonic() + self.timeout_s
        while not self._pub.matching_status.matching:
            if time.monotonic() >= deadline:
                return False
            time.sleep(POLL_S)
        return True


class ZenohListener(Transport):
    """A receive-only transport for a bus that watches a running robot (`sage record
    --attach`): the robot's publications on ``topics`` come in; nothing published in this
    process leaves it (its launcher's health stays here)."""

    def __init__(self, robot: RemoteRobot, topics: list[str]) -> None:
        self.robot = robot
        self.topics = [check_topic(t) for t in topics]
        self.bad_frames = 0

    def attach(self, deliver: Callable[[str, Any], None]) -> None:
        for topic in self.topics:
            self.robot.subscribe(topic, deliver, self._bad_frame)

    def _bad_frame(self, why: str) -> None:
        self.bad_frames += 1
        if self.bad_frames == 1:
            _log.warning("bad frame dropped: %s", why)

    def send(self, topic: str, msg: Any) -> None:
        return None

    def close(self) -> None:
        self.robot.close()
