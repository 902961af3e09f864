"""The words of planned tours and their control, for the offline intent rules (``intents.py``).

- A tour to plan: a stated time ("I have ten minutes"), "show me the <plural>" naming
  several places, or a liking ("I like robots", "we are into 3D printing", "interested in")
  that a place answers. :func:`plan_slot` says which interests (None: not a tour to plan,
  e.g. "show me the café" is a drive).
- Control of the running tour: "pause (the tour)", "skip (this one)", "next stop",
  "resume", "continue the tour", "stop/end the tour" (:func:`control_command`).
"""

from __future__ import annotations

import re

from sage_robot.brain import tours
from sage_robot.core.places import Places


def _any(*patterns: str) -> re.Pattern[str]:
    return re.compile("|".join(f"(?:{p})" for p in patterns))


TOUR_PLAN = _any(
    r"\b(i|we) (have|got|have got|only have|have only)\b.*\b(minutes?|mins?|hours?|half an hour)\b",
    r"\bshow (me|us) (the |some |all the |your )?\w+s\b",
    r"\b(i|we) (like|love|enjoy|am into|are into)\b",
    r"\binterested in\b",
)
LIKING = re.compile(r"\b(i|we) (like|love|enjoy|am into|are into)\b|\binterested in\b")
TOUR_CONTROL = (
    ("stop", _any(r"\b(stop|end|finish|cancel|quit|abort) (the|this|our) tour\b", r"\bno more tour")),
    ("pause", _any(r"\bpause\b", r"\btake a break\b")),
    ("skip", _any(r"\bskip\b", r"\bnext stop\b", r"\bmove on\b")),
    ("resume", _any(r"^(resume|continue|carry on|keep going)\b", r"\b(resume|continue) the tour\b",
                    r"\b(let us|lets) (continue|go on|carry on|keep going)\b")),
)  # fmt: skip
TOUR_CONTROLS = _any(*(p.pattern for _, p in TOUR_CONTROL))


def control_command(t: str) -> str:
    """The command ``t`` (prepared words that :data:`TOUR_CONTROLS` found) gives."""
    return next(c for c, p in TOUR_CONTROL if p.search(t))


def plan_slot(t: str, places: Places) -> str | None:
    """The interests of a tour to plan ("" for none: only a time), or None when the words
    name one place and no liking ("show me the café" is a drive)."""
    interests = tours.interests_of(t)
    fits = tours.candidates(places, interests, tours.package_kb()) if interests else []
    if tours.parse_budget_s(t) is None and (not fits or (len(fits) < 2 and not LIKING.search(t))):
        return None
    return " and ".join(interests)
