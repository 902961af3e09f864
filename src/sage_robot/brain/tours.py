"""Tours planned for a visitor: which places, in which order, and how long it takes.

"I have ten minutes, show me the labs", "I like robots and 3D printing": the request is
parsed into a time budget (:func:`parse_budget_s`) and interests (:func:`interests_of`);
each interest picks the places whose name, aliases and description (and, weaker, their
knowledge-base page) share its words, rarer words weighing more (:func:`candidates`). The
chosen places are put in route order from the robot (every order tried for a few stops,
nearest neighbour then 2-opt for more; :func:`route_order`) with path lengths from a
``distance(a, b)`` function, and the lowest-ranked stops are dropped until driving
(length / cruise speed) plus dwelling at every stop fits the budget (:func:`plan_tour`).

Pure functions over :class:`~sage_robot.core.places.Places`; the distances come from the
caller (the tour node's path lengths on the map, or straight lines).
"""

from __future__ import annotations

import functools
import itertools
import math
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from sage_robot.brain.matching import content_words, match_place
from sage_robot.core.msgs.tour import TourPlan, TourStop
from sage_robot.core.places import Place, Places

START = ""  # the robot's own position in a distance function's arguments
DWELL_S = 30.0  # at each stop: the welcome and a look around (s)
CRUISE_FRACTION = 0.6  # average speed over a leg (turns, people, slow zones) / top speed
DETOUR_FACTOR = 1.3  # path length / straight-line distance, when no map gives path lengths
MAX_STOPS = 8  # a tour with no budget keeps at most this many stops
EXACT_ORDER_MAX = 10  # up to this many stops the shortest order is exact (Held-Karp: n² 2ⁿ steps)
KB_WEIGHT = 0.4  # a word found only on a place's knowledge-base page counts this much
KEEP_FRACTION = 0.6  # an interest keeps the places scoring at least this share of its best
NOT_ON_TOURS = frozenset({"DOCKING_STATION", "BATHROOMS"})
SECONDS_PER_MINUTE = 60.0
# Words of a tour request that say nothing about what to see.
TOUR_WORDS = frozenset(
    """have has got tour tours guided quick short long time minute minutes hour hours only left
    spare give interested into about something anything stuff things thing cool fun also too
    would could able enjoy see show me us around""".split()  # noqa: SIM905
)
_NUMBER = {
    "a": 1, "an": 1, "one": 1, "two": 2, "three": 3, "four": 4, "five": 5, "six": 6, "seven": 7,
    "eight": 8, "nine": 9, "ten": 10, "eleven": 11, "twelve": 12, "fifteen": 15, "twenty": 20,
    "thirty": 30, "forty": 40, "forty five": 45, "fifty": 50, "sixty": 60, "ninety": 90,
}  # fmt: skip
_NUM = r"(\d+(?:\.\d+)?|" + "|".join(sorted((re.escape(k) for k in _NUMBER), key=len, reverse=True)) + ")"
_DURATION = re.compile(
    rf"\b(?:(half an hour)|(a quarter of an hour)|{_NUM}\s*(minutes?|mins?|hours?|hrs?))\b"
)
_SPLIT = re.compile(r"\s*(?:,|;|\band\b|\bor\b|\bplus\b|\bas well as\b)\s*")

Distance = Callable[[str, str], float]  # path length (m) between two places by name; START = the robot


def parse_budget_s(text: str) -> float | None:
    """The time a visitor says they have, in seconds: "ten minutes" → 600; None when unsaid."""
    t = text.lower()
    m = _DURATION.search(t)
    if m is None:
        return None
    if m.group(1):
        return 30 * SECONDS_PER_MINUTE
    if m.group(2):
        return 15 * SECONDS_PER_MINUTE
    raw, unit = m.group(3), m.group(4)
    value = float(raw) if raw[0].isdigit() else float(_NUMBER[raw])
    return value * SECONDS_PER_MINUTE * (60 if unit.startswith("h") else 1)


def without_duration(text: str) -> str:
    return _DURATION.sub(" ", text.lower())


def interests_of(text: str) -> list[str]:
    """The things a visitor wants to see, one phrase each: "robots and 3D printing" → both."""
    out = []
    for part in _SPLIT.split(without_duration(text)):
        words = [w for w in content_words(part) if w not in TOUR_WORDS and not w.isdigit()]
        if words:
            out.append(" ".join(words))
    return out


def kb_keywords(folder: Path) -> dict[str, set[str]]:
    """Place code name → content words of the first section of its knowledge-base page
    (``# Title (CODE)`` then "What happens here"); {} when the folder has none."""
    found: dict[str, set[str]] = {}
    title = re.compile(r"^#\s*.*\(([A-Z0-9_]+)\)\s*$")
    for doc in sorted(folder.glob("*.md")) if folder.is_dir() else []:
        try:
            lines = doc.read_text(encoding="utf-8").strip().splitlines()
        except (OSError, UnicodeDecodeError):
            continue
        m = title.match(lines[0]) if lines else None
        if m is None:
            continue
        first_section = itertools.takewhile(
            lambda ln: not ln.startswith("## ") or ln.startswith("## What"), lines[1:]
        )
        body = list(first_section)
        found[m.group(1)] = set(content_words(" ".join(body)))
    return found


@functools.cache
def package_kb() -> dict[str, set[str]]:
    """:func:`kb_keywords` of the package's own knowledge-base pages (read once)."""
    from sage_robot.core.paths import package_data

    return kb_keywords(package_data("kb", "places"))


@dataclass(frozen=True)
class Candidate:
    place: Place
    score: float  # summed over the interests it answers
    why: str  # the first interest it answers


def _words(place: Place) -> set[str]:
    return set(content_words(" ".join([place.name, *place.aliases, place.description])))


def candidates(
    places: Places | Sequence[Place], interests: Sequence[str], kb: dict[str, set[str]] | None = None
) -> list[Candidate]:
    """Places answering the interests, best first (ties in the places' own order); every
    place when no interest is given. Rarer words weigh more, as in the brain's matching."""
    pool = [p for p in places if p.name not in NOT_ON_TOURS]
    if not interests:
        return [Candidate(p, 1.0, "") for p in pool]
    docs = {p.name: _words(p) for p in pool}
    kb = kb or {}
    n = len(pool)
    score: dict[str, float] = {}
    why: dict[str, str] = {}
    for interest in interests:
        wanted = set(interest.split())
        weight = {w: math.log((n + 1) / (1 + sum(w in d for d in docs.values()))) + 0.1 for w in wanted}
        got = {}
        for p in pool:
            s = sum(weight[w] for w in wanted & docs[p.name])
            s += KB_WEIGHT * sum(weight[w] for w in (wanted & kb.get(p.name, set())) - docs[p.name])
            if s > 0:
                got[p.name] = s
        best = max(got.values(), default=0.0)
        for name, s in got.items():
            if s >= KEEP_FRACTION * best:
                score[name] = score.get(name, 0.0) + s
                why.setdefault(name, interest)
    ranked = sorted((p for p in pool if p.name in score), key=lambda p: -score[p.name])  # stable: file order
    return [Candidate(p, score[p.name], why[p.name]) for p in ranked]


def route_length(order: Sequence[str], distance: Distance) -> float:
    """Length (m) of the open route from the robot through ``order``."""
    return sum(distance(a, b) for a, b in zip((START, *order)[: len(order)], order, strict=True))


def shortest_order(names: Sequence[str], distance: Distance) -> list[str]:
    """The shortest open route from the robot through every name (Held-Karp dynamic
    programming over subsets: exact, n² 2ⁿ steps)."""
    n = len(names)
    d = [[distance(a, b) for b in names] for a in names]
    # best[(mask, j)] = (length of the shortest route through ``mask`` ending at j, previous j)
    best: dict[tuple[int, int], tuple[float, int]] = {}
    for j in range(n):
        best[(1 << j, j)] = (distance(START, names[j]), -1)
    for mask in range(1, 1 << n):
        for j in range(n):
            here = best.get((mask, j))
            if here is None:
                continue
            for k in range(n):
                if mask & (1 << k):
                    continue
                key, length = (mask | (1 << k), k), here[0] + d[j][k]
                if key not in best or length < best[key][0] - 1e-12:
                    best[key] = (length, j)
    full = (1 << n) - 1
    j = min(range(n), key=lambda e: best[(full, e)][0])
    order, mask = [], full
    while j >= 0:
        order.append(names[j])
        j, mask = best[(mask, j)][1], mask & ~(1 << j)
    return order[::-1]


def route_order(names: Sequence[str], distance: Distance) -> list[str]:
    """``names`` in the order of the shortest route from the robot (open: no return)."""
    if len(names) <= 1:
        return list(names)
    if len(names) <= EXACT_ORDER_MAX:
        return shortest_order(names, distance)
    order: list[str] = []
    left = list(names)
    here = START
    while left:  # nearest neighbour ...
        nxt = min(left, key=lambda n: distance(here, n))
        order.append(nxt)
        left.remove(nxt)
        here = nxt
    improved = True
    while improved:  # ... then 2-opt: reverse a stretch while that shortens the route
        improved = False
        for i, j in itertools.combinations(range(len(order)), 2):
            trial = order[:i] + order[i : j + 1][::-1] + order[j + 1 :]
            if route_length(trial, distance) < route_length(order, distance) - 1e-9:
                order, improved = trial, True
    return order


def _stops(order: Sequence[str], distance: Distance, speed_mps: float, why: dict[str, str],
           titles: dict[str, str]) -> tuple[list[TourStop], float]:
    stops, drive_m = [], 0.0
    for a, b in zip((START, *order)[: len(order)], order, strict=True):
        leg = distance(a, b)
        drive_m += leg
        stops.append(TourStop(b, titles.get(b, ""), round(leg, 1), round(leg / speed_mps, 1), why.get(b, "")))
    return stops, drive_m


def plan_tour(
    chosen: Sequence[Candidate],
    distance: Distance,
    speed_mps: float,
    budget_s: float | None = None,
    dwell_s: float = DWELL_S,
    max_stops: int = MAX_STOPS,
    titles: dict[str, str] | None = None,
    distances: str = "map",
) -> TourPlan:
    """The best-ranked of ``chosen`` that fit ``budget_s`` (None: no limit), in route order.
    ``speed_mps`` is the cruise speed. Not ok (with a reason) when nothing is chosen or not
    even the nearest stop fits."""
    if speed_mps <= 0 or not math.isfinite(speed_mps):
        raise ValueError(f"cruise speed must be positive, got {speed_mps}")
    if not chosen:
        return TourPlan(False, reason="no place fits the request", distances=distances)
    ranked = list(chosen)
    limit = budget_s if budget_s is not None and budget_s > 0 else math.inf
    kept = list(ranked) if math.isfinite(limit) else ranked[:max_stops]  # a budget weighs every candidate
    dropped = [c.place.name for c in ranked[len(kept):]]

    def total(order: Sequence[str]) -> float:
        return route_length(order, distance) / speed_mps + dwell_s * len(order)

    order = route_order([c.place.name for c in kept], distance)
    while kept and (total(order) > limit or len(kept) > max_stops):
        # Drop the lowest-ranked stop; among equals, the one whose removal saves most time.
        low = min(c.score for c in kept)
        worst = max((c for c in kept if c.score == low),
                    key=lambda c: total(order) - total([n for n in order if n != c.place.name]))  # fmt: skip
        kept.remove(worst)
        dropped.insert(0, worst.place.name)
        order = route_order([c.place.name for c in kept], distance)
    if not kept:
        nearest = min(ranked, key=lambda c: distance(START, c.place.name))
        need = total([nearest.place.name])
        reason = f"even the nearest stop needs about {minutes_phrase(need)}"
        return TourPlan(False, budget_s=limit, dropped=tuple(dropped), distances=distances, reason=reason)
    why = {c.place.name: c.why for c in kept}
    stops, drive_m = _stops(order, distance, speed_mps, why, titles or {})
    return TourPlan(
        True,
        tuple(stops),
        round(total(order), 1),
        round(drive_m, 1),
        dwell_s,
        0.0 if math.isinf(limit) else limit,
        tuple(dropped),
        distances,
    )


def named_places(names: Sequence[str], places: Places) -> tuple[list[Place], list[str]]:
    """The places ``names`` mean (name, alias or a misheard name), and those that match none."""
    found: list[Place] = []
    unknown: list[str] = []
    for n in names:
        hit = places.get(n) if n in places else (m.place if (m := match_place(n, places)) else None)
        if hit is None:
            unknown.append(n)
        elif hit not in found:
            found.append(hit)
    return found, unknown


def straight_line(places: Places, start: tuple[float, float] | None) -> Distance:
    """Distances when no map is at hand: straight lines × :data:`DETOUR_FACTOR`; the robot
    at ``start`` (None: it stands at the first stop, legs from it count nothing)."""

    def distance(a: str, b: str) -> float:
        if a == START and start is None:
            return 0.0
        pa = start if a == START else (places.get(a).pose.x, places.get(a).pose.y)
        pb = places.get(b).pose
        assert pa is not None
        return DETOUR_FACTOR * math.hypot(pb.x - pa[0], pb.y - pa[1])

    return distance


def minutes(seconds: float) -> int:
    """Whole minutes, rounded up, for speech."""
    return max(1, math.ceil(seconds / SECONDS_PER_MINUTE))


def minutes_phrase(seconds: float) -> str:
    """ "1 minute", "7 minutes"."""
    n = minutes(seconds)
    return f"{n} minute" if n == 1 else f"{n} minutes"
