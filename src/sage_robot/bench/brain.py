"""Brain: offline intent accuracy (dev and held-out phrasings) and LLM first-sentence latency.

Accuracy: the offline classifier on ``data/brain/phrasings_dev.yaml`` (used while
developing) and ``phrasings_heldout.yaml`` (never looked at while tuning), against the
seed's places in ``data/brain/places.yaml``. An utterance counts as right when both the
intent and the place (for navigation and place questions) are right.

Dialogues: multi-turn conversations (``data/brain/dialogues_dev.yaml`` and the held-out
``dialogues_heldout.yaml``) scored turn by turn on the first tool call and its place, with
the real sentence embedder for the semantic fallback (:mod:`sage_robot.bench.brain_dialogues`);
``--no-semantic`` scores keywords and dialogue state alone.

Tours: visitors' tour requests ("I have ten minutes, show me the labs") planned by the
offline brain and the tour node on the default building's map, scored on a valid plan within
the stated time, started on "yes" (:mod:`sage_robot.bench.brain_tours`).

KB answers: the offline brain with the real knowledge base (SQLite, shipped corpus) on the
KB's question set (``data/kb/questions.yaml``): how many reach the KB, how many it
answers, and how many of those from the document the set names; and how many questions
of ``data/brain/off_topic.yaml`` it wrongly answers instead of "I do not know".

Latency: the real ``openai`` client against the scripted OpenAI-compatible server on
loopback; each turn streams a reply in small pieces with ``--token-delay-ms`` between
them (a model's token rate), and the time from sending the turn to the first sentence
handed to speech is measured, for a plain reply and for a turn with one tool round.
"""

from __future__ import annotations

import argparse
import asyncio
import time
from collections import Counter
from typing import Any

REPLY = "Sure thing, the Guelly Delly is right around the corner. Follow me and I will show you the way."
PIECE_CHARS = 4  # characters per streamed piece (about one token)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--turns", type=int, default=30, help="latency turns per case")
    p.add_argument("--token-delay-ms", type=float, default=5.0, help="pause between streamed pieces (ms)")
    p.add_argument("--no-semantic", action="store_true", help="dialogues without the sentence embedder")


def _embedder_source(off: bool) -> Any:
    """all-MiniLM-L6-v2 from its installed package, loaded on first use (None: keywords only)."""
    if off:
        return None
    from sage_robot.brain.semantic import cached_source
    from sage_robot.kb.embed import MiniLmEmbedder

    return cached_source(MiniLmEmbedder)


def accuracy(which: str) -> dict[str, Any]:
    import yaml

    from sage_robot.brain.intents import classify
    from sage_robot.core.paths import package_data
    from sage_robot.core.places import load_places

    places = load_places(package_data("brain", "places.yaml"))
    rows = yaml.safe_load(package_data("brain", f"phrasings_{which}.yaml").read_text())["phrasings"]
    right = 0
    per_intent: Counter[str] = Counter()
    per_intent_right: Counter[str] = Counter()
    t0 = time.perf_counter()
    for r in rows:
        text, intent, place = str(r[0]), r[1], (r[2] if len(r) > 2 else "")
        got = classify(text, places)
        ok = got.name == intent and got.place_name == place
        right += ok
        per_intent[intent] += 1
        per_intent_right[intent] += ok
    ms = (time.perf_counter() - t0) * 1000 / max(1, len(rows))
    return {
        "phrasings": len(rows),
        "accuracy": round(right / len(rows), 3),
        "classify_ms": round(ms, 2),
        "intents_with_misses": {
            k: f"{per_intent_right[k]}/{n}" for k, n in per_intent.items() if per_intent_right[k] < n
        },
    }


async def _kb_answers() -> dict[str, Any]:
    import tempfile

    import yaml

    from sage_robot.brain.offline import OfflineBrain
    from sage_robot.brain.phrases import DONT_KNOW
    from sage_robot.brain.robot import RobotLink
    from sage_robot.brain.speech import split_sentences
    from sage_robot.brain.tools import ToolContext, ToolRegistry
    from sage_robot.core import topics
    from sage_robot.core.bus import Bus
    from sage_robot.core.config import Settings
    from sage_robot.core.config.areas import KbSettings
    from sage_robot.core.msgs.kb import SearchRequest, SearchResponse
    from sage_robot.core.paths import package_data
    from sage_robot.kb.service import KbService

    with tempfile.TemporaryDirectory() as tmp:
        service = KbService.from_settings(KbSettings(path=f"{tmp}/kb.sqlite3"))
        try:
            service.ensure_corpus()
            bus = Bus()

            async def search(req: SearchRequest) -> SearchResponse:
                return SearchResponse(tuple(await asyncio.to_thread(service.search, req.query, req.top_k)))

            bus.serve(topics.KB_SEARCH, search)
            robot = RobotLink(bus, package_data("brain", "places.yaml"))
            brain = OfflineBrain(ToolRegistry(ToolContext(robot, Settings())))
            out: dict[str, Any] = {}
            rows = yaml.safe_load(package_data("kb", "questions.yaml").read_text())
            for part, held in (("dev", False), ("heldout", True)):
                c: Counter[str] = Counter()
                for row in (r for r in rows if bool(r.get("heldout")) == held):
                    brain.reset()
                    result = await brain.respond(row["q"])
                    c["questions"] += 1
                    searches = [t for t in result.tool_calls if t.name == "kb_search"]
                    if not searches:
                        continue
                    c["reach_kb"] += 1
                    if result.reply == DONT_KNOW:
                        continue
                    c["answered"] += 1
                    passages = searches[0].result.data["passages"]
                    first = result.sentences[0]
                    sources = [p["source"] for p in passages if first in split_sentences(p["text"])]
                    c["right_document"] += bool(sources) and sources[0].endswith(row["doc"])
                out[f"questions_{part}"] = dict(c)
            off = yaml.safe_load(package_data("brain", "off_topic.yaml").read_text())
            for part in ("development", "heldout"):
                wrong = [q for q in off[part] if (await brain.respond(q)).reply != DONT_KNOW]
                out[f"off_topic_{part}"] = {"questions": len(off[part]), "answered_wrongly": len(wrong)}
            await robot.close()
            return out
        finally:
            service.close()


async def _latency(turns: int, delay_s: float) -> dict[str, Any]:
    import datetime as dt

    import numpy as np

    from sage_robot.brain.llm import LlmBrain
    from sage_robot.brain.robot import RobotLink
    from sage_robot.brain.scripted import ScriptedServer, Stream, call, text_chunks
    from sage_robot.brain.tools import ToolContext, ToolRegistry
    from sage_robot.core.bus import Bus
    from sage_robot.core.config import Settings
    from sage_robot.core.paths import package_data

    out: dict[str, Any] = {}
    async with ScriptedServer() as server:
        settings = Settings.model_validate({"llm": {"base_url": server.base_url, "max_retries": 0}})
        bus = Bus()
        robot = RobotLink(bus, package_data("brain", "places.yaml"))
        brain = LlmBrain(
            settings, ToolRegistry(ToolContext(robot, settings)), bus.clock, today=lambda: dt.date(2026, 1, 1)
        )
        reply = Stream(text_chunks(REPLY, PIECE_CHARS), delay_s=delay_s)
        for case, script in (
            ("plain", [reply]),
            ("one_tool_round", [call(("describe_place", {"name": "the cafe"})), reply]),
        ):
            firsts, totals = [], []
            for i in range(turns + 1):  # the first turn warms the client up and is not counted
                server.add(*script)
                brain.reset()
                t0 = time.perf_counter()
                first: list[float] = []

                def heard(sentence: str, first: list[float] = first) -> None:
                    first.append(time.perf_counter())

                await brain.respond("take me to the cafe", heard)
                if i:
                    firsts.append(first[0] - t0)
                    totals.append(time.perf_counter() - t0)
            f, t = np.array(firsts) * 1000, np.array(totals) * 1000
            out[case] = {
                "first_sentence_ms_p50": round(float(np.percentile(f, 50)), 1),
                "first_sentence_ms_p95": round(float(np.percentile(f, 95)), 1),
                "whole_reply_ms_p50": round(float(np.percentile(t, 50)), 1),
            }
        await robot.close()
    return out


def _dialogues(args: argparse.Namespace) -> dict[str, Any]:
    from sage_robot.bench.brain_dialogues import run_dialogues

    t0 = time.perf_counter()
    out = run_dialogues(_embedder_source(args.no_semantic))
    return {"semantic": not args.no_semantic, **out, "seconds": round(time.perf_counter() - t0, 1)}


def _tours() -> dict[str, Any]:
    from sage_robot.bench.brain_tours import run_tours  # tours planned for visitors, scored

    return run_tours()


def run(args: argparse.Namespace) -> dict[str, Any]:
    import math

    first_end = REPLY.index(". ") + 1
    floor_ms = math.ceil(first_end / PIECE_CHARS) * args.token_delay_ms
    return {
        "bench": "brain",
        "offline_dev": accuracy("dev"),
        "offline_heldout": accuracy("heldout"),
        "offline_dialogues": _dialogues(args),
        "tours": _tours(),
        "offline_kb_answers": asyncio.run(_kb_answers()),
        "llm_latency": {
            "turns": args.turns,
            "token_delay_ms": args.token_delay_ms,
            "first_sentence_stream_floor_ms": floor_ms,  # the pieces before its period, at that rate
            **asyncio.run(_latency(args.turns, args.token_delay_ms / 1000)),
        },
    }
