"""`sage chat` (a conversation in the terminal) and `sage ask "text" --json` (one turn).

Both use the configured brain: the LLM agent when ``llm.base_url`` is set, else the
offline brain. ``--sim`` starts the simulated robot, navigation and the knowledge base
(:data:`SIM_NODES`) in this process first, so "take me to the café" really drives;
without it, tools that need navigation say it is not running. ``--with NODE`` adds single
nodes (e.g. ``kb`` for knowledge questions).

``sage chat --json`` reads one utterance per line from standard input and prints one JSON
reply per line (the fields of ``sage ask --json``), all in one conversation, so multi-turn
dialogues can be scripted. The offline brain's semantic fallback gets all-MiniLM-L6-v2
(the KB's embedder, from its installed package), loaded the first time it is needed.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
import threading
from collections.abc import AsyncIterator, Awaitable, Callable, Sequence
from typing import Any

from sage_robot.app.launcher import Launcher
from sage_robot.app.profiles import PROFILES
from sage_robot.app.runtime import make_context, run_launcher
from sage_robot.core.config import load_profile
from sage_robot.core.errors import ConfigError
from sage_robot.core.node import NodeContext

ASK_TIMEOUT_S = 120.0  # longest a single `sage ask` turn may take
# What `--sim` starts: the simulated robot, navigation and the knowledge base; not the
# voice (its models load for seconds), the web server (:8000) or Foxglove (:8765).
SIM_NODES = (
    "sim_world", "mcu_sim", "serial_bridge", "map_server", "localization", "navigator", "kb", "brain",
    "tour",  # planned tours: "I have ten minutes, show me the labs"
)  # fmt: skip
PROMPT = "you> "
CHAT_SESSION = "chat"  # the dialogue session of a `sage chat` conversation


class LazyEmbedder:
    """all-MiniLM-L6-v2, loaded on the first ``embed`` (a turn that needs the semantic
    fallback), so a chat that never needs it does not pay for it."""

    name = "all-MiniLM-L6-v2"
    dim = 384

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._model: Any = None

    def embed(self, texts: Sequence[str]) -> Any:
        with self._lock:
            if self._model is None:
                from sage_robot.kb.embed import MiniLmEmbedder

                self._model = MiniLmEmbedder()
        return self._model.embed(texts)


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser("chat", help="talk with the robot's brain in the terminal")
    _common(p)
    p.add_argument("--json", action="store_true",
                   help="read one utterance per line from stdin, print one JSON reply per line")  # fmt: skip
    p.set_defaults(func=run_chat)
    p = sub.add_parser("ask", help="one turn with the brain: prints the reply (and tool calls)")
    p.add_argument("text", help="what the visitor says")
    p.add_argument("--json", action="store_true", help="print the reply, sentences and tool calls as JSON")
    _common(p)
    p.set_defaults(func=run_ask)


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--sim", action="store_true", help="start the simulated robot in this process")
    p.add_argument("--with", dest="nodes", action="append", default=[], metavar="NODE",
                   help="also start this node (repeatable), e.g. kb")  # fmt: skip
    p.add_argument("--offline", action="store_true", help="use the offline brain even if an LLM is set")


def _settings(args: argparse.Namespace) -> Any:
    overrides: dict[str, Any] = {"sim": {"speed": 1.0}}
    if args.offline:
        overrides["llm"] = {"base_url": ""}
    return load_profile(args.profile, overrides)


def _node_names(args: argparse.Namespace, with_brain: bool) -> tuple[list[str], bool]:
    """Nodes to start and whether the clock is simulated."""
    names = [n for n, _ in PROFILES["sim"] if n in SIM_NODES] if args.sim else []
    names += [n for n in args.nodes if n not in names]
    if with_brain and "brain" not in names:
        names.append("brain")
    if not with_brain:
        names = [n for n in names if n != "brain"]
    return names, bool(args.sim)


def _session(
    args: argparse.Namespace, with_brain: bool, body: Callable[[NodeContext], Awaitable[Any]]
) -> Any:
    """Start the nodes, run ``body`` beside them, stop everything when it returns."""
    from sage_robot.core.embedding import SENTENCE_EMBEDDER

    settings = _settings(args)
    names, simulated = _node_names(args, with_brain)
    ctx = make_context(settings, simulated=simulated)
    ctx.resources[SENTENCE_EMBEDDER] = LazyEmbedder()
    specs = specs_for_names(names, dict(PROFILES["sim"]) if args.sim else {})
    out: dict[str, Any] = {}

    async def after_start(launcher: Launcher) -> None:
        async def wrapped() -> None:
            try:
                out["value"] = await body(ctx)
            except BaseException as exc:  # surface it after the launcher stops
                out["error"] = exc
            finally:
                launcher.request_stop()

        asyncio.get_running_loop().create_task(wrapped())

    asyncio.run(run_launcher(ctx, specs, after_start=after_start))
    if "error" in out:
        raise out["error"]
    return out.get("value")


def specs_for_names(names: list[str], critical: dict[str, bool]) -> list[Any]:
    from sage_robot.app.launcher import NodeSpec
    from sage_robot.app.registry import node_class

    return [NodeSpec(n, node_class(n), critical.get(n, False)) for n in names]


# ---------------------------------------------------------------- sage ask


def run_ask(args: argparse.Namespace) -> int:
    if not args.text.strip():
        raise ConfigError("sage ask: the text to say is empty")

    async def one_turn(ctx: NodeContext) -> dict[str, Any]:
        replies: list[dict[str, Any]] = []
        await _direct_turns(ctx, _one(args.text), replies.append)
        return replies[0]

    result = _session(args, with_brain=False, body=one_turn)
    if args.json:
        print(json.dumps(result))
    else:
        print(result["reply"])
    return 0


async def _one(text: str) -> AsyncIterator[str]:
    yield text


async def _direct_turns(
    ctx: NodeContext, lines: AsyncIterator[str], out: Callable[[dict[str, Any]], None]
) -> None:
    """Each utterance of ``lines`` answered by a brain made here, in one conversation;
    ``out`` gets each turn's ``as_dict()``."""
    from sage_robot.brain.node import make_brain
    from sage_robot.brain.robot import RobotLink
    from sage_robot.core import topics
    from sage_robot.core.embedding import SENTENCE_EMBEDDER
    from sage_robot.core.msgs import BatteryState
    from sage_robot.core.paths import waypoints_yaml

    robot = RobotLink(ctx.bus, waypoints_yaml(ctx.settings))
    sub = ctx.bus.subscribe(topics.BATTERY, BatteryState, robot.on_battery, maxsize=1)
    try:
        embedder = ctx.resources.get(SENTENCE_EMBEDDER)
        brain = make_brain(ctx.settings, robot, ctx.clock, lambda: embedder)
        async for line in lines:
            result = await asyncio.wait_for(brain.respond(line, session=CHAT_SESSION), ASK_TIMEOUT_S)
            out(result.as_dict())
    finally:
        sub.close()
        await robot.close()


# ---------------------------------------------------------------- sage chat


def _stdin_lines(loop: asyncio.AbstractEventLoop, queue: asyncio.Queue[str | None]) -> None:
    """A daemon thread: each line typed goes to the queue; None at end of input."""

    def read() -> None:
        for line in sys.stdin:
            loop.call_soon_threadsafe(queue.put_nowait, line.rstrip("\n"))
        loop.call_soon_threadsafe(queue.put_nowait, None)

    threading.Thread(target=read, name="chat-stdin", daemon=True).start()


def run_chat(args: argparse.Namespace) -> int:
    if args.json:
        _session(args, with_brain=False, body=_json_conversation)
        return 0

    async def conversation(ctx: NodeContext) -> None:
        from sage_robot.core import topics
        from sage_robot.core.msgs import Text

        queue: asyncio.Queue[str | None] = asyncio.Queue()
        _stdin_lines(asyncio.get_running_loop(), queue)
        says = ctx.bus.subscribe(topics.SAY, Text, lambda m: print(f"sage> {m.data}", flush=True))
        kind = "LLM" if ctx.settings.llm.base_url else "offline"
        print(f"Talking with the {kind} brain. Type a line; Ctrl-D or 'quit' ends.", flush=True)
        try:
            while True:
                print(PROMPT, end="", flush=True)
                line = await queue.get()
                if line is None or line.strip().lower() in ("quit", "exit"):
                    return
                if line.strip():
                    await _chat_turn(ctx, line)
        finally:
            says.close()

    _session(args, with_brain=True, body=conversation)
    print()
    return 0


async def _json_conversation(ctx: NodeContext) -> None:
    """`sage chat --json`: one JSON line out per non-blank line in, until end of input."""
    queue: asyncio.Queue[str | None] = asyncio.Queue()
    _stdin_lines(asyncio.get_running_loop(), queue)

    async def lines() -> AsyncIterator[str]:
        while (line := await queue.get()) is not None:
            if line.strip():
                yield line

    await _direct_turns(ctx, lines(), lambda reply: print(json.dumps(reply), flush=True))


async def _chat_turn(ctx: NodeContext, line: str) -> None:
    from sage_robot.brain.base import Utterance
    from sage_robot.core import topics

    handle = await ctx.bus.actions.send_goal(topics.CONVERSE, Utterance(line, CHAT_SESSION))
    async for sentence in handle.feedback():
        print(f"sage> {sentence.data}", flush=True)
    result = await handle.result()
    if not result.ok:
        print(f"(the brain did not answer: {result.message})", flush=True)
