"""Semantic fallback: what a visitor meant, by sentence embeddings, when keywords fail.

The embedder is the one the knowledge base ships (all-MiniLM-L6-v2, loaded offline from an
installed package), reached through :class:`~sage_robot.core.embedding.SentenceEmbedder`
(the brain may not import ``kb``). Each place is embedded as several short texts (its
spoken name, aliases, description, and the everyday words :data:`matching.SYNONYMS` maps
to it); an utterance's score for a place is its best cosine with them. A few intents that
never move the robot have example sentences too.

The guess carries its confidence: the best cosine and its margin over the runner-up.
The offline brain never drives on a semantic guess alone: a good one is offered back
("Do you mean the bathrooms? Shall I take you there?"), a weak one gets a clarifying
question; only a sure one with a request to go ("..., take me there") drives.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from sage_robot.brain.intents import Intent
from sage_robot.brain.matching import SYNONYMS, content_words
from sage_robot.core.clock import Clock
from sage_robot.core.embedding import SentenceEmbedder
from sage_robot.core.errors import ConfigError
from sage_robot.core.places import Place, Places

PLACE_MAYBE = 0.38  # cosine at or above which a place is offered back ("Do you mean ...?")
PLACE_MARGIN = 0.07  # ... and by which it must beat the next place (else: which one?)
PLACE_SURE = 0.55  # cosine at or above which a visitor who asked to be taken is taken there
SURE_MARGIN = 0.15  # ... when it beats the next place by this much
INTENT_SURE = 0.60  # cosine at or above which an example sentence decides a non-driving intent

# Example sentences for intents that never move the robot (a wrong one costs a sentence).
INTENT_EXAMPLES: dict[str, tuple[str, ...]] = {
    "where_am_i": ("where are we right now", "what is this place we are in", "which room is this"),
    "battery": ("how much battery do you have left", "are you running out of power"),
    "capabilities": ("what are you able to do for me", "how can you help me", "what are you for"),
    "list_places": ("what is there to see here", "which places can you show me"),
    "goodbye": ("thanks for your help", "that is all for today, goodbye"),
    "small_talk": ("how are you doing today", "tell me something funny", "who built you"),
}

EmbedderSource = Callable[[], "SentenceEmbedder | None"]
_log = logging.getLogger("sage.brain.semantic")


@dataclass(frozen=True)
class Guess:
    """The best place (or intent) for an utterance, with how sure the embedding is."""

    place: Place | None = None
    score: float = 0.0  # best cosine
    margin: float = 0.0  # best cosine minus the runner-up place's
    runner_up: Place | None = None
    intent: str = ""  # a non-driving intent, when an example sentence is close enough
    intent_score: float = 0.0

    @property
    def offered(self) -> bool:
        """Confident enough to offer the place back to the visitor."""
        return self.place is not None and self.score >= PLACE_MAYBE and self.margin >= PLACE_MARGIN

    @property
    def sure(self) -> bool:
        """Confident enough to drive there when the visitor asked to be taken."""
        return self.place is not None and self.score >= PLACE_SURE and self.margin >= SURE_MARGIN


def place_texts(place: Place) -> list[str]:
    """The short texts a place is known by: spoken name, aliases, description, and the
    everyday words that stand for it ("food, eat, hungry" for a café)."""
    texts = {place.name.replace("_", " ").lower(), *place.aliases}
    if place.description:
        texts.add(place.description)
    words = set(content_words(" ".join([place.name, *place.aliases, place.description])))
    wants = [k for k, v in SYNONYMS.items() if v in words]
    if wants:
        texts.add("a place to " + ", ".join(wants))
    return sorted(t for t in texts if t)


class SemanticMatcher:
    """Place and intent guesses from an embedder that is loaded on first use (in a worker
    thread, through ``clock.offload``); without one, every guess is empty."""

    def __init__(self, source: EmbedderSource) -> None:
        self._source = source
        self._lock = threading.Lock()
        self._key: tuple[str, ...] = ()
        self._owners: list[Place] = []
        self._vectors = np.zeros((0, 0), dtype=np.float32)
        self._intents: list[str] = []
        self._intent_vectors = np.zeros((0, 0), dtype=np.float32)
        self._broken = ""  # why the embedder could not load: keywords only from then on

    async def guess(self, text: str, places: Places, clock: Clock) -> Guess:
        """The guess for ``text`` (CPU work, offloaded)."""
        if not text.strip() or not len(places):
            return Guess()
        return await clock.offload(self._guess, text, tuple(places))

    def _guess(self, text: str, places: Sequence[Place]) -> Guess:
        if self._broken:
            return Guess()
        with self._lock:
            try:
                embedder = self._source()
                if embedder is None:
                    return Guess()
                self._index(embedder, places)
                query = embedder.embed([text])[0]
            except (ConfigError, OSError, ImportError) as exc:  # model package missing or broken
                self._broken = str(exc) or type(exc).__name__
                _log.warning("semantic fallback off, keywords only: %s", self._broken)
                return Guess()
            return self._score(query)

    def _index(self, embedder: SentenceEmbedder, places: Sequence[Place]) -> None:
        key = tuple(f"{p.name}|{p.description}|{'|'.join(p.aliases)}" for p in places)
        if key == self._key:
            return
        texts: list[str] = []
        self._owners = []
        for p in places:
            for t in place_texts(p):
                texts.append(t)
                self._owners.append(p)
        self._vectors = embedder.embed(texts)
        if not self._intents:
            self._intents = [k for k, examples in INTENT_EXAMPLES.items() for _ in examples]
            self._intent_vectors = embedder.embed([e for ex in INTENT_EXAMPLES.values() for e in ex])
        self._key = key

    def _score(self, query: np.ndarray) -> Guess:
        best: dict[str, tuple[float, Place]] = {}
        for score, place in zip(self._vectors @ query, self._owners, strict=True):
            if place.name not in best or score > best[place.name][0]:
                best[place.name] = (float(score), place)
        ranked = sorted(best.values(), key=lambda b: -b[0])
        top, runner = ranked[0], (ranked[1] if len(ranked) > 1 else (0.0, None))
        intent_scores = self._intent_vectors @ query
        i = int(np.argmax(intent_scores))
        return Guess(
            place=top[1],
            score=round(top[0], 3),
            margin=round(top[0] - runner[0], 3),
            runner_up=runner[1],
            intent=self._intents[i],
            intent_score=round(float(intent_scores[i]), 3),
        )


def cached_source(load: Callable[[], SentenceEmbedder | None]) -> EmbedderSource:
    """``load`` called once, on first use (in the worker thread the guess runs in)."""
    lock = threading.Lock()
    held: list[SentenceEmbedder | None] = []

    def source() -> SentenceEmbedder | None:
        with lock:
            if not held:
                held.append(load())
            return held[0]

    return source


def intent_from_guess(intent: Intent, guess: Guess) -> Intent:
    """What the semantic guess makes of an utterance the rules did not place."""
    if intent.name == "unknown" and guess.intent and guess.intent_score >= INTENT_SURE:
        return Intent(guess.intent, slot="", how="semantic")
    if intent.name == "navigate" and guess.sure:
        return Intent("navigate", guess.place, intent.slot, "semantic")
    if guess.offered:
        return Intent("suggest", guess.place, intent.slot, "semantic")
    if intent.name == "navigate" and intent.how == "reference":
        return Intent("clarify", slot="navigate", how="reference")
    return intent
