"""Which place a visitor meant: by name, alias, a misheard name, or what the place is for.

Three passes, best first:

1. a place's name or alias appears word for word ("take me to the clean room");
2. a fuzzy match of the words against names and aliases, for speech-to-text errors
   ("gully deli", "mecha tronics lab", "clean rum");
3. content words matched against names, aliases and descriptions, weighted by how rare
   each word is among the places ("I want to see the robots" → Valpo Robotics).

Pure functions over :class:`~sage_robot.core.places.Places`; rapidfuzz does the fuzzy part.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from rapidfuzz import fuzz

from sage_robot.core.places import Place, Places, normalize

FUZZY_MIN = 78.0  # rapidfuzz score (0..100) a misheard name must reach
PARTIAL_MIN_CHARS = 6  # names shorter than this are not searched for inside longer text
PARTIAL_WEIGHT = 0.95  # a name found inside longer text ranks just below a whole match
KEYWORD_MIN = 1.0  # summed rarity weight of matched words a description match needs
EXACT_SCORE = 100.0
STEM_MIN_CHARS = 4  # a stem keeps at least this many letters ("labs" → "lab" is the exception)
# Words naming a kind of place rather than one place ("take me to the labs": which one?).
CATEGORY_WORDS = frozenset({"lab", "laboratory", "workshop", "shop", "space", "center", "studio"})
FUZZY_TIE = 2.0  # places whose fuzzy score is this close to the best are equally likely ("ece lab")

# Homophones speech-to-text writes for the numbers in lab names ("ece lab too").
_STT_NUMBERS = [
    (re.compile(r"\b(lab|room|station|floor) (too|two)\b"), r"\1 2"),
    (re.compile(r"\b(lab|room|station|floor) (won|one)\b"), r"\1 1"),
    (re.compile(r"\be c e\b"), "ece"),
    (re.compile(r"\bcentre\b"), "center"),
]
# Words that say nothing about which place is meant.
STOP_WORDS = frozenset(
    """i me my we us our you your it its they them their he she is are was be am do does
    did can could would will shall should may might must want wanna like love need needs
    see go going get got take bring show lead head visit find where what which who how
    when why there here this that these those some any all of in on at for from with by
    and or but so if then just please now again over back up down out into around let
    lets let's im i'm id i'd okay ok yes no not very really much more most place places
    room""".split()  # noqa: SIM905
)
# Concepts a visitor names by what they want rather than by the place's name.
SYNONYMS = {
    "food": "cafe",
    "eat": "cafe",
    "hungry": "cafe",
    "lunch": "cafe",
    "breakfast": "cafe",
    "coffee": "cafe",
    "snack": "cafe",
    "toilet": "restroom",
    "loo": "restroom",
    "washroom": "restroom",
    "charge": "charging",
    "recharge": "charging",
    "tutor": "tutoring",
    "study": "tutoring",
}


@dataclass(frozen=True)
class PlaceMatch:
    place: Place
    score: float  # 0..100 for name matches; keyword matches report their weight * 10
    how: str  # "exact", "fuzzy" or "keyword"
    tied: tuple[Place, ...] = ()  # other places that fit as well: the visitor must choose


def clean(text: str) -> str:
    """:func:`normalize` plus fixes for what speech-to-text does to numbers."""
    t = normalize(text.replace("é", "e"))
    for pattern, repl in _STT_NUMBERS:
        t = pattern.sub(repl, t)
    return t


def stem(word: str) -> str:
    """A crude English stem, enough to meet 'robots' with 'robotics', 'printers' with 'printing'."""
    for suffix in ("ations", "ation", "ics", "ing", "ers", "er", "es"):
        if word.endswith(suffix) and len(word) - len(suffix) >= STEM_MIN_CHARS:
            return word[: -len(suffix)]
    if word.endswith("s") and not word.endswith("ss") and len(word) >= STEM_MIN_CHARS:
        return word[:-1]
    return word


def content_words(text: str) -> list[str]:
    words = [SYNONYMS.get(w, w) for w in clean(text).split() if w not in STOP_WORDS]
    return [stem(w) for w in words]


def _spoken(places: Places) -> list[tuple[str, Place]]:
    return [(clean(s), p) for p in places for s in {*p.spoken_names(), clean(p.name)} if s]


def exact_match(text: str, places: Places) -> PlaceMatch | None:
    """A name or alias that appears word for word; the longest such wins."""
    wanted = f" {clean(text)} "
    found = [(len(s), p) for s, p in _spoken(places) if f" {s} " in wanted]
    if not found:
        return None
    return PlaceMatch(max(found, key=lambda f: f[0])[1], EXACT_SCORE, "exact")


def fuzzy_match(text: str, places: Places, minimum: float = FUZZY_MIN) -> PlaceMatch | None:
    """The name or alias closest to ``text`` (whole, or found inside it); places that fit
    just as well ("ece lab": lab 1 and lab 2) are listed in ``tied``."""
    wanted = clean(text)
    if not wanted:
        return None
    best: dict[str, tuple[float, Place]] = {}
    for spoken, place in _spoken(places):
        score = fuzz.ratio(wanted, spoken)
        if len(spoken) >= PARTIAL_MIN_CHARS and len(wanted) > len(spoken):
            score = max(score, PARTIAL_WEIGHT * fuzz.partial_ratio(spoken, wanted))
        if score >= minimum and score > best.get(place.name, (-1.0, place))[0]:
            best[place.name] = (float(score), place)
    if not best:
        return None
    ranked = sorted(best.values(), key=lambda b: -b[0])  # stable: the file's order among equals
    top, place = ranked[0]
    tied = tuple(p for s, p in ranked[1:] if s >= top - FUZZY_TIE)
    return PlaceMatch(place, top, "fuzzy", tied)


def _keyword_scores(text: str, places: Places) -> list[tuple[float, Place]]:
    """(summed rarity weight of the matched words, place), best first."""
    wanted = set(content_words(text))
    if not wanted or not len(places):
        return []
    docs = {p.name: set(content_words(" ".join([p.name, *p.aliases, p.description]))) for p in places}
    n = len(docs)
    weight = {w: math.log((n + 1) / (1 + sum(w in d for d in docs.values()))) + 0.1 for w in wanted}
    scored = []
    for p in places:
        hits = wanted & docs[p.name]
        if hits:
            scored.append((sum(weight[w] for w in hits), p))
    scored.sort(key=lambda s: s[0], reverse=True)  # stable: the file's order among equals
    return scored


def keyword_match(text: str, places: Places) -> PlaceMatch | None:
    """Content words against each place's name, aliases and description, rarer words weighing
    more; None when nothing fits or several places fit as well (see :func:`category_places`)."""
    scored = _keyword_scores(text, places)
    if not scored:
        return None
    top, place = scored[0]
    tie = len(scored) > 1 and scored[1][0] >= top - 1e-9
    if top < KEYWORD_MIN or tie:
        return None
    return PlaceMatch(place, round(10 * top, 1), "keyword")


def category_places(text: str, places: Places) -> tuple[Place, ...]:
    """The places of a kind ``text`` names and nothing else ("the labs", "a workshop"),
    when there are several: the visitor must choose."""
    words = content_words(text)
    if not words or not all(w in CATEGORY_WORDS for w in words):
        return ()
    scored = _keyword_scores(text, places)
    if len(scored) < 2 or scored[1][0] < scored[0][0] - 1e-9:
        return ()
    return tuple(p for s, p in scored if s >= scored[0][0] - 1e-9)


def match_place(text: str, places: Places) -> PlaceMatch | None:
    """The place ``text`` names, or None when nothing fits well enough."""
    return exact_match(text, places) or fuzzy_match(text, places) or keyword_match(text, places)


def places_with_theme(theme: str, places: Places) -> list[Place]:
    """Places whose name, aliases or description share a content word with ``theme``."""
    wanted = set(content_words(theme))
    out = []
    for p in places:
        doc = set(content_words(" ".join([p.name, *p.aliases, p.description])))
        if wanted & doc:
            out.append(p)
    return out
