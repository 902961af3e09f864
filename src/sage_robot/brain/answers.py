"""Answers from the knowledge base: is a passage about the question, and what to say of it.

The KB ranks passages by fusing full-text and vector ranks, so its top hit always exists,
even for "what is the capital of France?". Whether a passage really answers the question
is judged here from two pieces of evidence:

* ``similarity``: the KB's cosine similarity of query and passage vectors
  (all-MiniLM-L6-v2, -1..1; on the shipped corpus on-topic questions reach 0.3-0.7 and
  off-topic ones stay below 0.35);
* ``cover``: the share of the question's keywords (Snowball-stemmed, so "printed" meets
  "print", stop words left out) found in the passage's title, section or text.

A passage is relevant when its similarity alone is high, or when a fair similarity is
backed by half of the question's words, or when most of several keywords are there
(rare words such as "calculus homework" that the vectors miss). The answer is two or
three speakable sentences from the passage's best sentence on.
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from dataclasses import dataclass
from functools import lru_cache

import snowballstemmer

from sage_robot.brain.matching import STOP_WORDS
from sage_robot.brain.speech import split_sentences
from sage_robot.core.places import Place, Places

SIM_SURE = 0.40  # cosine similarity at which a passage is on topic by itself
SIM_MIN = 0.20  # cosine similarity a passage needs with half the keywords found
COVER_WITH_SIM = 0.5  # share of keywords found that, with SIM_MIN, makes a passage relevant
COVER_ALONE = 0.6  # share of keywords found that is enough without any similarity ...
MIN_WORDS_ALONE = 2  # ... when at least this many keywords are found
ANSWER_SENTENCES = 3
ANSWER_MAX_CHARS = 360
REPEAT_SHARE = 0.7  # a sentence whose keywords were this much said already adds nothing

# Words that say nothing about what is asked (besides matching.STOP_WORDS).
QUESTION_STOP_WORDS = frozenset(
    """a an the to about as be been being has have had having than too also only other
    own same such both each few off once under until while during before after above
    below between through again further nor per via yet whom whose something anything
    someone anyone somewhere anywhere thing things tell know say said ask
    valpo valparaiso university college engineering""".split()  # noqa: SIM905
)
_WORD = re.compile(r"[a-z0-9]+")
_STEMMER = snowballstemmer.stemmer("english")


@lru_cache(maxsize=4096)
def _stem(word: str) -> str:
    return str(_STEMMER.stemWord(word))


def keywords(text: str) -> set[str]:
    """Stemmed content words: 'How do I get something printed in 3D?' → {'print', '3d'}."""
    words = _WORD.findall(text.lower().replace("'s ", " ").replace("\u2019s ", " "))
    return {
        _stem(w) for w in words if len(w) > 1 and w not in STOP_WORDS and w not in QUESTION_STOP_WORDS
    }


@dataclass(frozen=True)
class Hit:
    """One KB passage as the brain sees it (from the ``kb_search`` tool's result)."""

    text: str
    title: str = ""
    section: str = ""
    similarity: float = 0.0  # cosine of query and passage vectors, -1..1 (0 = not known)

    @classmethod
    def from_tool(cls, data: dict[str, object]) -> Hit:
        sim = data.get("similarity", 0.0)
        return cls(
            text=str(data.get("text", "")),
            title=str(data.get("title", "")),
            section=str(data.get("section", "")),
            similarity=float(sim) if isinstance(sim, int | float) else 0.0,
        )


def cover(question: set[str], hit: Hit) -> float:
    """Share of the question's keywords found in the passage's title, section or text."""
    if not question:
        return 0.0
    found = question & keywords(" ".join((hit.title, hit.section, hit.text)))
    return len(found) / len(question)


def is_relevant(question: set[str], hit: Hit) -> bool:
    """Does ``hit`` answer a question with these keywords? (see the module docstring)"""
    if hit.similarity >= SIM_SURE:
        return True
    share = cover(question, hit)
    if hit.similarity >= SIM_MIN and share >= COVER_WITH_SIM:
        return True
    return share >= COVER_ALONE and round(share * len(question)) >= MIN_WORDS_ALONE


def best_hit(question: str, hits: Iterable[Hit]) -> Hit | None:
    """The first relevant passage in the KB's order (best first), or None."""
    wanted = keywords(question)
    if not wanted:
        return None
    for hit in hits:
        if split_sentences(hit.text) and is_relevant(wanted, hit):
            return hit
    return None


def trim(text: str, question: str = "", sentences: int = ANSWER_SENTENCES) -> str:
    """Up to ``sentences`` speakable sentences (about ANSWER_MAX_CHARS), from the one that
    shares most keywords with ``question`` (the first when none or no question)."""
    parts = split_sentences(text)
    if not parts:
        return ""
    wanted = keywords(question)
    scores = [len(keywords(s) & wanted) for s in parts]
    start = max(range(len(parts)), key=lambda i: scores[i])
    out: list[str] = []
    for s in parts[start : start + sentences]:
        if out and sum(len(x) + 1 for x in out) + len(s) > ANSWER_MAX_CHARS:
            break
        out.append(s)
    return " ".join(out)


def kb_answer(question: str, hits: Iterable[Hit | str]) -> str | None:
    """Two or three speakable sentences from the best relevant passage, or None."""
    found = best_hit(question, (h if isinstance(h, Hit) else Hit(h) for h in hits))
    return trim(found.text, question) if found else None


_PLACE_IN_TITLE = re.compile(r"\(([A-Z0-9_]+)\)")  # "Valpo Robotics (VALPO_ROBOTICS)"


def place_of(hit: Hit, places: Places) -> Place | None:
    """The place whose own document ``hit`` comes from (its title names it), else None."""
    m = _PLACE_IN_TITLE.search(hit.title)
    return places.get(m.group(1)) if m and m.group(1) in places else None


def names_place(hit: Hit, names: Iterable[str]) -> bool:
    """Is ``hit`` from a document about the place (its name or an alias in the title)?
    ``names`` are lower-case spoken names ("clean room", "cleanroom")."""
    title = " ".join(_WORD.findall(f"{hit.title} {hit.section}".lower().replace("_", " ")))
    return any(f" {n} " in f" {title} " for n in names if n)


def place_passage(question: str, hits: Iterable[Hit], names: Iterable[str]) -> Hit | None:
    """The passage that best describes a place: of those from the place's own document the
    one most similar to ``question`` ("what is X? <its description>"), else the first
    relevant one."""
    hits, names = list(hits), list(names)
    own = [h for h in hits if split_sentences(h.text) and names_place(h, names)]
    if own:
        return max(own, key=lambda h: h.similarity)  # max keeps the KB's order among ties
    return best_hit(question, hits)


def repeats(sentence: str, said: str) -> bool:
    """Does ``sentence`` mostly say again what ``said`` already said?"""
    words = keywords(sentence)
    return bool(words) and len(words & keywords(said)) / len(words) >= REPEAT_SHARE
