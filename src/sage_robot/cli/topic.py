"""`sage topic`: look at a running robot's topics over Zenoh (the robot runs with
``bus.transport: zenoh``; nothing is started here).

- ``sage topic list [--json]``: every topic the robot's processes publish, with types and counts.
- ``sage topic echo TOPIC [--count N] [--json]``: print messages as they come (one JSON line
  each with ``--json``; arrays and bytes are summarised otherwise).
- ``sage topic hz TOPIC [--seconds S] [--json]``: the topic's rate over S seconds.
- ``sage topic pub TOPIC JSON [--count N] [--rate HZ]``: publish on the robot's bus as the
  operator: the password comes from ``SAGE_OPERATOR_PASSWORD`` or the stored generated one
  (as `sage slam save`), and the robot checks it. JSON holds the message's fields; the type
  comes from the topic table (``core/topics.py``) or a ``"type"`` key.

``--connect tcp/HOST:PORT`` reaches a robot elsewhere (default: the profile's
``bus.zenoh.listen`` on this machine); every wait is bounded by ``--timeout``.
"""

from __future__ import annotations

import argparse
import itertools
import json
import queue
import sys
import time
from typing import Any

from sage_robot.core.errors import SageError

DEFAULT_ECHO_TIMEOUT_S = 30.0  # echo gives up after this long without a message
DEFAULT_HZ_WINDOW_S = 5.0
MAX_PUB_RATE_HZ = 100.0
INLINE_ARRAY_ITEMS = 8  # arrays up to this size are printed in full by echo without --json


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser("topic", help="list, echo, measure or publish a running robot's topics (Zenoh)")
    p.set_defaults(help_parser=p)
    tsub = p.add_subparsers(dest="topic_command", metavar="SUBCOMMAND")

    q = tsub.add_parser("list", help="topics the robot publishes, with their types")
    _common(q)
    q.set_defaults(func=run_list)

    q = tsub.add_parser("echo", help="print a topic's messages")
    q.add_argument("topic", help="topic name, e.g. /cmd_vel")
    q.add_argument("--count", type=int, help="stop after N messages")
    _common(q, DEFAULT_ECHO_TIMEOUT_S, "give up after this long without a message (s)")
    q.set_defaults(func=run_echo)

    q = tsub.add_parser("hz", help="a topic's publication rate")
    q.add_argument("topic", help="topic name, e.g. /scan")
    q.add_argument("--seconds", type=float, default=DEFAULT_HZ_WINDOW_S, help="how long to measure (s)")
    _common(q)
    q.set_defaults(func=run_hz)

    q = tsub.add_parser("pub", help="publish a message on the robot's bus (operator password)")
    q.add_argument("topic", help="topic name, e.g. /cmd_vel")
    q.add_argument("message", help='the message as JSON, e.g. \'{"linear_x": 0.1}\'')
    q.add_argument("--count", type=int, default=1, help="publish it N times")
    q.add_argument("--rate", type=float, default=10.0, help="publications per second with --count")
    _common(q)
    q.set_defaults(func=run_pub)


def _common(q: argparse.ArgumentParser, timeout: float | None = None, what: str = "") -> None:
    q.add_argument("--json", action="store_true", help="machine-readable output")
    q.add_argument("--connect", action="append", help="robot endpoint, e.g. tcp/10.0.0.5:7447 (repeatable)")
    q.add_argument(
        "--timeout", type=float, default=timeout, help=what or "how long to wait for the robot (s)"
    )


def _robot(args: argparse.Namespace) -> Any:
    from sage_robot.core.config import load_profile

    if args.timeout is not None and args.timeout <= 0:
        raise SageError(f"--timeout must be > 0 s, got {args.timeout:g}")
    settings = load_profile(args.profile)
    try:
        from sage_robot.core.transport.remote import RemoteRobot
    except ImportError as exc:
        hint = "pip install 'sage-robot[zenoh]'"
        raise SageError(f"`sage topic` needs the zenoh extra ({hint}): {exc}") from None
    # echo's --timeout is its silence limit; the link itself waits bus.zenoh.open_timeout_s.
    open_timeout = None if args.func is run_echo else args.timeout
    robot = RemoteRobot(settings.bus, args.connect, open_timeout)
    try:
        robot.require_connected()
    except SageError:
        robot.close()
        raise
    return robot


def run_list(args: argparse.Namespace) -> int:
    with _robot(args) as robot:
        topics = robot.topics()
    if args.json:
        print(json.dumps(topics))
        return 0
    if not topics:
        print("the robot answered but publishes no topics yet")
        return 0
    width = max(len(t) for t in topics)
    for name, info in topics.items():
        print(f"{name:<{width}}  {info['type']:<22} {info['published']:>9} published")
    return 0


def _stream(args: argparse.Namespace, robot: Any) -> queue.Queue[tuple[float, Any]]:
    """Messages on ``args.topic`` into a queue, with their arrival time (monotonic s)."""
    from sage_robot.core.transport.keys import check_topic

    check_topic(args.topic)
    inbox: queue.Queue[tuple[float, Any]] = queue.Queue()

    def on_error(why: str) -> None:
        print(f"sage topic: dropped a bad frame: {why}", file=sys.stderr)

    robot.subscribe(args.topic, lambda _name, msg: inbox.put((time.monotonic(), msg)), on_error)
    return inbox


def run_echo(args: argparse.Namespace) -> int:
    from sage_robot.core.msgs import to_dict

    if args.count is not None and args.count < 1:
        raise SageError(f"--count must be >= 1, got {args.count}")
    with _robot(args) as robot:
        inbox = _stream(args, robot)
        shown = 0
        while args.count is None or shown < args.count:
            try:
                _, msg = inbox.get(timeout=args.timeout)
            except queue.Empty:
                raise SageError(f"no message on {args.topic} within {args.timeout:g} s") from None
            data = to_dict(msg)
            print(json.dumps(data if args.json else _summary(data)), flush=True)
            shown += 1
    return 0


def _summary(value: Any) -> Any:
    """A message dict for people: long arrays and bytes as a short description."""
    if isinstance(value, dict):
        if "__ndarray__" in value and value["shape"] and _size(value["shape"]) > INLINE_ARRAY_ITEMS:
            return f"<{value['dtype']} array {'x'.join(str(n) for n in value['shape'])}>"
        if "__ndarray__" in value:
            return value["__ndarray__"]
        if "__bytes__" in value:
            return f"<{len(value['__bytes__']) * 3 // 4} bytes>"
        return {k: _summary(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_summary(v) for v in value]
    return value


def _size(shape: list[int]) -> int:
    n = 1
    for d in shape:
        n *= d
    return n


def run_hz(args: argparse.Namespace) -> int:
    if args.seconds <= 0:
        raise SageError(f"--seconds must be > 0, got {args.seconds:g}")
    with _robot(args) as robot:
        inbox = _stream(args, robot)
        time.sleep(args.seconds)
    stamps = [t for t, _ in list(inbox.queue)]
    gaps = [b - a for a, b in itertools.pairwise(stamps)]
    hz = (len(stamps) - 1) / (stamps[-1] - stamps[0]) if len(stamps) > 1 and stamps[-1] > stamps[0] else 0.0
    report = {
        "topic": args.topic,
        "messages": len(stamps),
        "seconds": args.seconds,
        "hz": round(hz, 3),
        "interval_min_s": round(min(gaps), 4) if gaps else None,
        "interval_max_s": round(max(gaps), 4) if gaps else None,
    }
    if args.json:
        print(json.dumps(report))
    elif gaps:
        print(
            f"{args.topic}: {hz:.2f} Hz ({len(stamps)} messages in {args.seconds:g} s; "
            f"intervals {min(gaps):.4f} to {max(gaps):.4f} s)"
        )
    else:
        print(f"{args.topic}: {len(stamps)} message(s) in {args.seconds:g} s")
    return 0 if stamps else 1


def parse_message(topic: str, text: str) -> Any:
    """The message ``text`` (JSON fields) describes for ``topic``; one-line errors."""
    from sage_robot.core import topics
    from sage_robot.core.bus import Topic
    from sage_robot.core.msgs import from_dict
    from sage_robot.core.transport.keys import check_topic

    check_topic(topic)
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise SageError(f"message is not valid JSON: {exc}") from None
    if not isinstance(data, dict):
        raise SageError(f"message must be a JSON object of fields, got {type(data).__name__}")
    known = {str(t): t.msg_type for t in vars(topics).values() if isinstance(t, Topic)}
    declared = known.get(topic)
    if declared is None and "type" not in data:
        raise SageError(f'{topic} is not in the topic table: give the message type as "type" in the JSON')
    try:
        return from_dict({"type": declared.__name__ if declared else None, **data}, declared)
    except ValueError as exc:
        raise SageError(f"bad message for {topic}: {exc}") from None


def run_pub(args: argparse.Namespace) -> int:
    from sage_robot.cli.slam import client_password
    from sage_robot.core.config import load_profile

    msg = parse_message(args.topic, args.message)
    if args.count < 1:
        raise SageError(f"--count must be >= 1, got {args.count}")
    if not 0 < args.rate <= MAX_PUB_RATE_HZ:
        raise SageError(f"--rate must be in (0, {MAX_PUB_RATE_HZ:g}] Hz, got {args.rate:g}")
    password = client_password(load_profile(args.profile))
    with _robot(args) as robot:
        for i in range(args.count):
            if i:
                time.sleep(1.0 / args.rate)
            robot.publish(args.topic, msg, password)
    if not args.json:
        print(f"published {type(msg).__name__} on {args.topic} ({args.count}x)")
    else:
        print(json.dumps({"topic": args.topic, "type": type(msg).__name__, "count": args.count}))
    return 0
