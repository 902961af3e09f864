"""Zenoh key expressions of a SAGE robot, and the Zenoh session its settings describe.

Keys (``<robot>`` is ``bus.robot_id``; a topic name loses its leading slash)::

    sage/<robot>/topic/<name>    every publication (e.g. sage/sage/topic/cmd_vel)
    sage/<robot>/info/<zid>      queryable: the process's topics, types and counts (JSON)
    sage/<robot>/last/<name>     queryable: the last message the process published on a topic
    sage/<robot>/pub/<name>      queryable: publish a message on the robot's bus, with the
                                 operator password as the query's attachment
"""

from __future__ import annotations

import json
import re
from typing import Any

from sage_robot.core.config.bus import ZenohSettings
from sage_robot.core.errors import ConfigError, SageError

TOPIC_NAME = re.compile(r"^(/[A-Za-z0-9_]+)+$")  # ROS names: no wildcards, no empty chunks
PREFIX = "sage"
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


def session_config(z: ZenohSettings, listen: list[str], connect: list[str]) -> Any:
    """A ``zenoh.Config``: ``config_file`` first, then mode, scouting and endpoints."""
    import zenoh

    try:
        cfg = zenoh.Config.from_file(z.config_file) if z.config_file else zenoh.Config()
        cfg.insert_json5("mode", json.dumps(z.mode))
        cfg.insert_json5("scouting/multicast/enabled", json.dumps(z.multicast_scouting))
        if listen or not z.config_file:
            cfg.insert_json5("listen/endpoints", json.dumps(listen))
        if connect or not z.config_file:
            cfg.insert_json5("connect/endpoints", json.dumps(connect))
    except (zenoh.ZError, OSError) as exc:
        raise ConfigError(f"bus.zenoh: {_one_line(exc)}") from None
    return cfg


def open_session(cfg: Any, what: str) -> Any:
    """``zenoh.open`` with a one-line error (a port in use, a bad endpoint, a TLS file)."""
    import zenoh

    try:
        return zenoh.open(cfg)
    except zenoh.ZError as exc:
        raise SageError(f"{what}: cannot open the Zenoh session: {_one_line(exc)}") from None


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return text if len(text) < 300 else text[:297] + "..."
