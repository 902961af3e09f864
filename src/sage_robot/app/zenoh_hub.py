"""The process groups' meeting point: a Zenoh router in the supervisor's process.

Every group's bus is a Zenoh peer that connects to this router (explicit loopback endpoint,
no scouting) and learns the other groups' endpoints from its gossip, so two groups talk
directly; tools (``sage topic``, ``sage status``) reach the robot at this one address. The
supervisor uses the same session for the few topics it reads (each group's health,
``/clock``) and writes (the merged ``/sage/health``, a stop on ``/cmd_vel`` when a critical
group dies), with the bus's wire encoding.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import os
from collections.abc import Callable
from typing import Any

from sage_robot.core.config.bus import DEFAULT_TX_QUEUE, ONE_POOL_RUNTIME
from sage_robot.core.errors import SageError
from sage_robot.core.transport import wire
from sage_robot.core.transport.keys import RUNTIME_ENV, TX_QUEUE_KEY, kind_key, open_session, topic_key

_log = logging.getLogger("sage.process_groups.hub")


class ZenohHub:
    """A Zenoh router listening on ``endpoint``; subscribe and publish bus messages on it."""

    def __init__(
        self,
        endpoint: str,
        robot_id: str = "sage",
        runtime: str = ONE_POOL_RUNTIME,
        tx_queue: int = DEFAULT_TX_QUEUE,
    ) -> None:
        import zenoh

        if runtime:  # one thread pool, as the groups' sessions (before Zenoh starts its pools)
            os.environ.setdefault(RUNTIME_ENV, runtime)
        self.endpoint, self.robot = endpoint, robot_id
        cfg = zenoh.Config()
        try:
            cfg.insert_json5("mode", json.dumps("router"))
            cfg.insert_json5("scouting/multicast/enabled", "false")
            cfg.insert_json5("listen/endpoints", json.dumps([endpoint]))
            cfg.insert_json5("connect/endpoints", "[]")
            cfg.insert_json5(TX_QUEUE_KEY, json.dumps(tx_queue))  # a stop on /cmd_vel must not be dropped
        except zenoh.ZError as exc:
            raise SageError(f"process groups: bad endpoint {endpoint!r}: {exc}") from None
        self.session = open_session(cfg, "process groups")
        self._last: dict[str, bytes] = {}  # topic -> the last frame published here
        # Tools ask the last message of a topic (`sage status` reads /sage/health so).
        last = self.session.declare_queryable(kind_key(robot_id, "last"), self._on_last)
        self._declared: list[Any] = [last]
        self.rejected = 0  # frames that did not decode

    def subscribe(self, topic: str, callback: Callable[[Any], None]) -> None:
        """Call ``callback(msg)`` on the running event loop for each message on ``topic``."""
        import zenoh

        loop = asyncio.get_running_loop()

        def on_sample(sample: Any) -> None:  # Zenoh's thread
            try:
                msg = wire.decode(sample.payload.to_bytes())
            except wire.WireError as exc:
                self.rejected += 1
                _log.warning("bad frame on %s dropped: %s", topic, exc)
                return
            with contextlib.suppress(RuntimeError):  # the loop closed: shutting down
                loop.call_soon_threadsafe(callback, msg)

        # On Zenoh's network thread, not a Python thread of its own: one hand-off less.
        handler = zenoh.handlers.Callback(on_sample, indirect=False)
        self._declared.append(self.session.declare_subscriber(topic_key(self.robot, topic), handler))

    def publish(self, topic: str, msg: Any) -> None:
        frame = wire.encode(msg)
        self._last[topic] = frame
        self.session.put(topic_key(self.robot, topic), frame)

    def _on_last(self, query: Any) -> None:  # Zenoh's thread
        import zenoh

        for topic, frame in list(self._last.items()):
            key = kind_key(self.robot, "last", topic[1:])
            if query.key_expr.intersects(zenoh.KeyExpr(key)):
                query.reply(key, frame)

    def close(self) -> None:
        for decl in self._declared:
            with contextlib.suppress(Exception):
                decl.undeclare()
        self._declared.clear()
        with contextlib.suppress(Exception):
            self.session.close()
