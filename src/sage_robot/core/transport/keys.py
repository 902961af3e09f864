"""Zenoh key expressions of a SAGE robot, and the Zenoh session its settings describe.

Keys (``<robot>`` is ``bus.robot_id``; a topic name loses its leading slash)::

    sage/<robot>/topic/<name>    every publication (e.g. sage/sage/topic/cmd_vel)
    sage/<robot>/info/<zid>      queryable: the process's topics, types and counts (JSON)
    sage/<robot>/last/<name>     queryable: the last message the process published on a topic
    sage/<robot>/pub/<name>      queryable: publish a message on the robot's bus, with the
                                 operator password as the query's attachment
"""

from __future__ import annotations

import atexit
import json
import os
import re
import threading
from pathlib import Path
from typing import Any

from sage_robot.core.config.bus import ZenohSettings
from sage_robot.core.errors import ConfigError, SageError

TOPIC_NAME = re.compile(r"^(/[A-Za-z0-9_]+)+$")  # ROS names: no wildcards, no empty chunks
PREFIX = "sage"
RUNTIME_ENV = "ZENOH_RUNTIME"  # Zenoh reads its thread pools from here, once
ZENOH_THREADS = re.compile(r"^(app|rx|tx|net|acc)-\d+$")  # the names of Zenoh's pool threads
TX_QUEUE_KEY = "transport/link/tx/queue/size/data"  # batches a link queues at the data priority
ANY_ADDRESS = re.compile(r"/(0\.0\.0\.0|\[::\]):")  # a listen address a tool cannot connect to


def check_topic(name: str) -> str:
    """``name`` if it can be a topic on the wire, else a one-line error."""
    if not TOPIC_NAME.match(name):
        raise SageError(
            f"bad topic name {name!r}: it starts with '/' and has only letters, digits, '_' "
            "between slashes (e.g. /cmd_vel)"
        )
    return name


def topic_key(robot: str, name: str) -> str:
    return f"{PREFIX}/{robot}/topic/{check_topic(name)[1:]}"


def kind_key(robot: str, kind: str, rest: str = "**") -> str:
    """``sage/<robot>/<kind>/<rest>``: kind is topic, info, last or pub."""
    return f"{PREFIX}/{robot}/{kind}/{rest}"


def topic_of(robot: str, kind: str, key: str) -> str | None:
    """The topic name a key of ``kind`` names, or None if it names none."""
    head = f"{PREFIX}/{robot}/{kind}/"
    if not key.startswith(head):
        return None
    name = "/" + key[len(head) :]
    return name if TOPIC_NAME.match(name) else None


def tool_endpoints(z: ZenohSettings) -> list[str]:
    """Where a tool on this machine reaches the robot: its connect endpoints in client mode
    (the router), else its listen endpoints (any-address ones as loopback)."""
    if z.mode == "client":
        return list(z.connect)
    return [ANY_ADDRESS.sub("/127.0.0.1:", e) for e in z.listen]


def session_config(z: ZenohSettings, listen: list[str] | None, connect: list[str] | None) -> Any:
    """A ``zenoh.Config``: ``config_file`` first, then the profile's keys over it (with a file,
    only those the profile sets). ``listen``/``connect`` given here override both (a tool
    listens nowhere and connects to the robot)."""
    import zenoh

    if z.runtime:  # before the process's first session starts Zenoh's pools
        os.environ.setdefault(RUNTIME_ENV, z.runtime)
    if z.config_file and not Path(z.config_file).is_file():
        raise ConfigError(f"bus.zenoh.config_file: {z.config_file} not found")
    explicit = z.model_fields_set if z.config_file else set(type(z).model_fields)
    keys: dict[str, Any] = {}
    if "mode" in explicit:
        keys["mode"] = z.mode
    if "multicast_scouting" in explicit:
        keys["scouting/multicast/enabled"] = z.multicast_scouting
    if "tx_queue" in explicit:
        keys[TX_QUEUE_KEY] = z.tx_queue
    if "shared_memory" in explicit:
        keys["transport/shared_memory/enabled"] = z.shared_memory
    if listen is not None or "listen" in explicit:
        keys["listen/endpoints"] = list(z.listen) if listen is None else listen
    if connect is not None or "connect" in explicit:
        keys["connect/endpoints"] = list(z.connect) if connect is None else connect
    try:
        cfg = zenoh.Config.from_file(z.config_file) if z.config_file else zenoh.Config()
        for key, value in keys.items():
            cfg.insert_json5(key, json.dumps(value))
    except (zenoh.ZError, OSError) as exc:
        raise ConfigError(f"bus.zenoh: {_one_line(exc)}") from None
    return cfg


def open_session(cfg: Any, what: str) -> Any:
    """``zenoh.open`` with a one-line error (a port in use, a bad endpoint, a TLS file). The
    session is closed at exit if its owner did not close it."""
    import zenoh

    try:
        session = zenoh.open(cfg)
    except zenoh.ZError as exc:
        raise SageError(f"{what}: cannot open the Zenoh session: {_one_line(exc)}") from None
    _close_at_exit(session)
    return session


def _close_at_exit(session: Any) -> None:
    """Zenoh's callback threads are non-daemon Python threads: the interpreter waits for them
    *before* ``atexit`` handlers run, so a session left open hangs the exit.
    ``threading._register_atexit`` runs first (``concurrent.futures`` uses it for the same
    reason)."""

    def close() -> None:
        if not session.is_closed():
            session.close()

    register = getattr(threading, "_register_atexit", None)
    if register is None:  # pragma: no cover - CPython >= 3.9 has it
        atexit.register(close)
    else:
        register(close)


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return text if len(text) < 300 else text[:297] + "..."
