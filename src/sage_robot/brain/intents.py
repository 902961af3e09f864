"""The offline brain's intent classifier: deterministic rules over cleaned words.

``classify(text, places)`` returns an :class:`Intent` (a name and, for navigation and
place questions, the place). Rules are tried in a fixed order (a table, not a chain of
ifs); the first that fires wins. Wake words and greetings at the start are stripped so
"hey jarvis, take me to the café" is a navigation request.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass

from sage_robot.brain import tour_intents
from sage_robot.brain.matching import (
    SYNONYMS,
    PlaceMatch,
    category_places,
    exact_match,
    fuzzy_match,
    keyword_match,
    match_place,
)
from sage_robot.core.places import Place, Places

INTENTS = (
    "greeting",
    "goodbye",
    "small_talk",
    "capabilities",
    "navigate",
    "where_is",
    "cancel",
    "where_am_i",
    "status",
    "battery",
    "ip_address",
    "tour",
    "tour_control",  # pause, resume, skip or stop the running tour (slot: the command)
    "list_places",
    "describe_place",
    "distance",  # how far a place is
    "suggest",  # a place guessed from what the visitor said, offered back (semantic fallback)
    "clarify",  # a question back: where to, or which of several places
    "question",
    "unknown",
)

_CONTRACTIONS = {
    "what's": "what is",
    "where's": "where is",
    "how's": "how is",
    "who's": "who is",
    "that's": "that is",
    "it's": "it is",
    "let's": "let us",
    "i'm": "i am",
    "i'd": "i would",
    "i'll": "i will",
    "don't": "do not",
    "can't": "can not",
    "you're": "you are",
    "we're": "we are",
}
WAKE_WORDS = ("hey jarvis", "jarvis", "hey sage", "sage", "robot", "okay", "ok", "um", "uh", "so", "well")
GREETING = re.compile(
    r"^(hi|hello|hey|hiya|howdy|greetings|yo|good (morning|afternoon|evening|day))( there)?\b"
)


def prepare(text: str) -> str:
    """Lower case, contractions expanded, punctuation gone, 'i p' → 'ip'."""
    t = text.lower().replace("’", "'").replace("é", "e")
    for short, long in _CONTRACTIONS.items():
        t = re.sub(rf"\b{re.escape(short)}\b", long, t)
    t = re.sub(r"[^a-z0-9' ]+", " ", t).replace("'", "")
    t = re.sub(r"\bi p\b", "ip", t)
    t = re.sub(r"\be c e\b", "ece", t)
    return " ".join(t.split())


def strip_wake(t: str) -> str:
    changed = True
    while changed:
        changed = False
        for w in WAKE_WORDS:
            if t.startswith(w + " "):
                t, changed = t[len(w) + 1 :], True
    return t


@dataclass(frozen=True)
class Intent:
    name: str
    place: Place | None = None
    slot: str = ""  # the words that named the place (or the tour theme, the question)
    how: str = ""  # how the place was matched
    choices: tuple[Place, ...] = ()  # places that fit the words equally well, the first included

    @property
    def place_name(self) -> str:
        return self.place.name if self.place else ""


def _any(*patterns: str) -> re.Pattern[str]:
    return re.compile("|".join(f"(?:{p})" for p in patterns))


CANCEL_FIRST = re.compile(r"^(stop|cancel|halt|abort|never ?mind|forget it|wait|hold on|freeze)\b")
CANCEL = _any(
    CANCEL_FIRST.pattern,
    r"\b(cancel|abort)\b",
    r"\bstop (moving|navigating|driving|going|the (tour|robot))\b",
    r"\bdo not go\b",
)
# What the robot is doing now ("why did you stop" is a question, not a cancel).
STATUS = _any(
    r"\bwhere are (you|we) (going|headed|heading)\b",
    r"\bwhere are you taking (me|us)\b",
    r"\bwhat are you (doing|up to)\b",
    r"\bwhy (arent|are) (you|we)( not)? (moving|going|driving)\b",
    r"\bwhy (is|isnt) (it|the robot)( not)? (moving|going|driving)\b",
    r"\bwhy (did|have) (you|we|it) stop",
    r"\bwhy can (you|we) not (move|go|drive)\b",
    r"\bare you (moving|stuck|stopped|broken)\b",
    r"\bwhat is (your|the robots) status\b",
)
IP = _any(r"\bip\b", r"\bnetwork address\b", r"\bon the network\b", r"\bip address", r"\bhost ?name\b")
BATTERY = _any(
    r"\bbattery\b",
    r"\bcharge level\b",
    r"\bpower level\b",
    r"\bare you charged\b",
    r"\bneed to (charge|recharge)\b",
    r"\b(how much|what is your) (charge|power)\b",
)
WHERE_AM_I = _any(
    r"\bwhere (am i|are we|are you)\b",
    r"^(what|which) (room|place|area|floor|part of the building|lab)( is this| are we in| am i in)",
    r"^what is this (place|room|lab)\b",
    r"\bwhat part of the building\b",
)
TOUR = _any(
    r"\btour\b", r"\bshow (me|us) around\b", r"\bwalk (me|us) around\b", r"\bshow (me|us) everything\b"
)
LIST_PLACES = _any(
    r"\bwhat (places|rooms|labs|locations)\b",
    r"\bwhich (places|rooms|labs|locations)\b",
    r"\bwhere (else )?can (you|we) (go|take)\b",
    r"\bwhat is there to (see|visit)\b",
    r"\blist (the |all |your )?(places|rooms|locations|destinations)\b",
    r"\bwhat can (i|we) (see|visit)\b",
    r"\bplaces (can|do) you\b",
)
WHERE_IS = re.compile(
    r"^(where is|where are|where can i find|where do i find|how do i get to|how do i find|"
    r"how can i get to|which way is|which way to|where would i find|do you know where)\b( the)?"
)
DESCRIBE = re.compile(
    r"^(tell me about|tell me more about|what is|what are|describe|what happens (in|at)|"
    r"what do (they|you|people) do (in|at)|what goes on (in|at)|what is in|what can i do (in|at))\b"
)
# The visitor asks to be taken along: a "where is" with this is a request to go.
CONSENT = _any(
    r"\b(take|bring|lead|walk|guide|escort) (me|us)\b",
    r"\blead the way\b",
    r"\b(let us|lets) go\b",
)
DISTANCE = _any(r"\bhow far\b", r"\bis (it|that|the \w+( \w+)?) far\b", r"\bhow long to (get|walk)\b")
# A question that asks where something can be had or done: answered from the map when a
# place fits ("is there somewhere I can get a coffee?"), else from the knowledge base.
LOCATE = _any(
    r"\bwhere (can|could|do|would|should|might) (i|we|you|one) (get|buy|grab|find|see|eat|go|study|"
    r"wash|charge|work|print|build|sit)\b",
    r"\b(is|are) there (a |an |any |some )?(\w+ )?(place|places|somewhere|anywhere|spot)\b",
    r"\bsomewhere (i|we) (can|could)\b",
    r"\bwhere (do|does) (students|people|they)\b",
)
CAPABILITIES = _any(
    r"^help\b",
    r"\bwhat can you do\b",
    r"\bwhat do you do\b",
    r"\bwhat are you able to\b",
    r"\byour (features|abilities|skills)\b",
    r"\bwhat can i ask\b",
    r"\bhow can you help\b",
    r"\bwhat kind of things\b",
    r"\bwhat are you (good|for)\b",
)
NAVIGATE = _any(
    r"\b(take|bring|lead|walk|guide|escort|drive) (me|us)\b",
    r"\b(lead|show) the way\b",
    r"^(go|head|drive|navigate|move|return|come)\b",
    r"\b(let us|lets|can we|could we|shall we) (go|head|visit|see)\b",
    r"\bi (want|would like|wanna|need|would love) to (go|see|visit|get|check out|use)\b",
    r"\bi need (the|a)\b",
    r"\bshow (me|us) (the|where)\b",
    r"\b(i am|we are) (hungry|thirsty)\b",
    r"\bnavigate\b",
)
GOODBYE = _any(
    r"\bthank",
    r"\bbye\b",
    r"\bgoodbye\b",
    r"\bsee you\b",
    r"\bhave a (nice|good|great)\b",
    r"\bthat is all\b",
    r"\bthats all\b",
    r"\bgood night\b",
    r"\bcheers\b",
)
SMALL_TALK = _any(
    r"\bhow are you\b",
    r"\bhow is it going\b",
    r"\byour name\b",
    r"\bwho are you\b",
    r"\bjoke\b",
    r"\bfunny\b",
    r"\bare you (alive|real|a robot|human|happy|smart|a person)\b",
    r"\bdo you like\b",
    r"\bhow old\b",
    r"\bwho (made|built|created|programmed) you\b",
    r"\bfavou?rite\b",
    r"\bwhat are you\b",
    r"\bdo you (have|get) (feelings|tired)\b",
)
QUESTION = re.compile(
    r"^(what|when|where|who|whom|whose|why|which|how|is|are|was|were|do|does|did|can|could|"
    r"will|would|should|tell me|explain|i wonder)\b"
)
# A question after a statement: "I need help with calculus, where can I go?"
QUESTION_INSIDE = re.compile(
    r"\b(what|when|where|who|which|why|how) (can|could|do|does|did|is|are|should|would|will|much|many|long)\b"
)
# Filler that may follow a greeting without making it anything else.
_GREETING_TAIL = re.compile(r"^(there|everyone|friend|buddy|how are you|how is it going)?\s*$")


def _slot_after(pattern: re.Pattern[str], t: str) -> str:
    m = pattern.search(t)
    return t[m.end() :].strip() if m else t


def _place(slot: str, whole: str, places: Places, strict: bool = False) -> PlaceMatch | None:
    """The place in the slot, else anywhere in the sentence; ``strict``: names only."""
    if strict:
        return exact_match(slot, places) or fuzzy_match(slot, places)
    found = match_place(slot, places) or (exact_match(whole, places) if whole != slot else None)
    if found is None and (not slot or REFERENCE.match(slot)):  # "..., take me there": the rest says where
        found = keyword_match(whole, places)
    return found


# "there", "it": a place named before (resolved by the dialogue state, brain/dialogue.py).
REFERENCE = re.compile(
    r"^(there|it|that|that place|that one|this place|this one|them|here)?"
    r"( again| then| instead| now| please| too| as well| around here)*$"
)


def _with_choices(name: str, hit: PlaceMatch, slot: str) -> Intent:
    choices = (hit.place, *hit.tied) if hit.tied else ()
    return Intent(name, hit.place, slot, hit.how, choices)


# ---------------------------------------------------------------- the rules, in order
# A rule runs when its pattern is found; it returns the intent, or None to let the
# rules after it try.
Rule = Callable[[str, Places], Intent | None]


def _named(name: str) -> Rule:
    """A rule whose pattern alone decides the intent."""
    return lambda t, places: Intent(name)


def _status(t: str, places: Places) -> Intent | None:
    """Unless the sentence starts with a cancel ("stop, where are you going": cancel)."""
    return None if CANCEL_FIRST.match(t) else Intent("status")


def _tour_theme(t: str) -> str:
    m = re.search(r"\btour (of|through|around) (the )?(.+)$", t)
    if not m:
        return ""
    theme = m.group(3).strip()
    return "" if theme in ("building", "place", "college", "campus", "everything") else theme


def _tour(t: str, places: Places) -> Intent | None:
    return Intent("tour", slot=_tour_theme(t))


def _tour_control(t: str, places: Places) -> Intent | None:
    return Intent("tour_control", slot=tour_intents.control_command(t))


def _tour_plan(t: str, places: Places) -> Intent | None:
    """A tour planned for the visitor's time or interests (said back, started on a "yes")."""
    slot = tour_intents.plan_slot(t, places)
    return None if slot is None else Intent("tour", slot=slot, how="plan")


def _where_is(t: str, places: Places) -> Intent | None:
    slot = _slot_after(WHERE_IS, t)
    hit = _place(re.sub(r"\b(located|at|from here)$", "", slot).strip(), t, places)
    if hit:  # "where is the bathroom, can you take me": consent is given, no need to ask
        return _with_choices("navigate" if CONSENT.search(t) else "where_is", hit, slot)
    return Intent("question", slot=t)


def _distance(t: str, places: Places) -> Intent | None:
    """'How far is the café?'; 'how far is it?' is left for the dialogue state to fill."""
    hit = exact_match(t, places) or fuzzy_match(_slot_after(DISTANCE, t), places)
    return Intent("distance", hit.place if hit else None, t, hit.how if hit else "")


def _locate(t: str, places: Places) -> Intent | None:
    """A where-can-I question the map answers: a place named, or an everyday need a place
    is for ("somewhere I can get a coffee"); else the rules after it (the KB knows more
    about which lab has robot arms than the places' descriptions do)."""
    needs = any(w in SYNONYMS for w in t.split())
    hit = exact_match(t, places) or (keyword_match(t, places) if needs else None)
    if hit is None:
        return None
    return _with_choices("navigate" if CONSENT.search(t) else "where_is", hit, t)


def _navigate(t: str, places: Places) -> Intent | None:
    slot = _slot_after(NAVIGATE, t)
    hit = _place(slot, t, places)
    if hit:
        return _with_choices("navigate", hit, slot)
    return Intent("navigate", None, slot, choices=category_places(slot, places))  # "the labs": which?


def _describe(t: str, places: Places) -> Intent | None:
    slot = _slot_after(DESCRIBE, t)
    hit = _place(re.sub(r"\b(about|for|used for)$", "", slot).strip(), t, places, strict=True)
    return Intent("describe_place", hit.place, slot, hit.how) if hit else None


def _question(t: str, places: Places) -> Intent | None:
    """A question of at least two words (the knowledge base is asked)."""
    return Intent("question", slot=t) if len(t.split()) >= 2 else None


RULES: tuple[tuple[re.Pattern[str], Rule], ...] = (
    (tour_intents.TOUR_CONTROLS, _tour_control),
    (STATUS, _status),
    (CANCEL, _named("cancel")),
    (IP, _named("ip_address")),
    (WHERE_AM_I, _named("where_am_i")),
    (LIST_PLACES, _named("list_places")),
    (tour_intents.TOUR_PLAN, _tour_plan),
    (TOUR, _tour),
    (DISTANCE, _distance),
    (WHERE_IS, _where_is),
    (NAVIGATE, _navigate),
    (BATTERY, _named("battery")),
    (DESCRIBE, _describe),
    (CAPABILITIES, _named("capabilities")),
    (SMALL_TALK, _named("small_talk")),
    (GOODBYE, _named("goodbye")),
    (LOCATE, _locate),
    (QUESTION, _question),
    (QUESTION_INSIDE, _question),
)


def classify(text: str, places: Places) -> Intent:
    """The intent of one visitor utterance."""
    t = strip_wake(prepare(text))
    if not t:
        return Intent("unknown")
    m = GREETING.match(t)
    if m:
        rest = strip_wake(t[m.end() :].strip())
        if _GREETING_TAIL.match(rest) or rest in WAKE_WORDS:
            return Intent("greeting")
        t = rest
    return _classify(t, places)


def _classify(t: str, places: Places) -> Intent:
    """The first intent a rule of :data:`RULES` gives, in order; else unknown."""
    for pattern, rule in RULES:
        if pattern.search(t):
            intent = rule(t, places)
            if intent is not None:
                return intent
    return Intent("unknown")


CONFIRM = re.compile(
    r"^(yes|yeah|yep|sure|ok|okay|please|please do|lets go|let us go|go ahead|take me there|"
    r"sounds good|absolutely|of course|why not)\b"
)
DECLINE = re.compile(r"^(no|nope|not now|no thanks|maybe later|nah)\b")
