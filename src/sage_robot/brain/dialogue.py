"""Dialogue state: what a conversation has said so far, so follow-ups resolve against it.

Each conversation (a session: the robot's own microphone and /talk page, a `sage chat`, a
web visitor) keeps its last few turns, the place last named, the place offered ("Shall I
take you there?"), the places offered as a choice ("the first or the second?") and the
last topic. :func:`resolve` turns "yes", "take me there", "the second one", "what's
there?", "how far is it?", "and where is it?" into an intent about that place.

The store is bounded (:data:`MAX_SESSIONS`, the conversation idle longest is dropped
first) and forgets a conversation idle for :data:`DIALOGUE_IDLE_S` on the clock.
"""

from __future__ import annotations

import re
from collections import OrderedDict, deque
from dataclasses import dataclass, field

from sage_robot.brain.intents import CONFIRM, DECLINE, REFERENCE, Intent
from sage_robot.brain.matching import exact_match, fuzzy_match
from sage_robot.core.places import Place, Places

DIALOGUE_IDLE_S = 120.0  # a conversation without a turn for this long (clock s) is forgotten
MAX_TURNS = 6  # turns remembered per conversation
MAX_SESSIONS = 32  # conversations kept at once
CONFIRM_MAX_WORDS = 5  # "yes please take me" is a confirmation; a longer sentence is not

# "there", "it", "that place": the place the conversation is about.
_REF = r"(there|it|that|that place|that one|this place|this one|them|they)"
REF_DESCRIBE = re.compile(
    rf"^(and |so )?(what is|what are|what is in|whats|tell me (more )?about|what happens|what goes on|"
    rf"what do (they|you|people) do|what can (i|we) (do|see))( in| at)? {_REF}\b"
)
REF_WHERE = re.compile(rf"^(and |so |but )?(where is|where are|how do i get to|how do we get to) {_REF}$")
ABOUT = re.compile(r"^(and |so )?(what|how) about (.+)$")
# "the second one", "number two", "the last": a pick among places offered as a choice.
_ORDINALS = {
    "first": 0, "one": 0, "1": 0, "1st": 0,
    "second": 1, "two": 1, "2": 1, "2nd": 1,
    "third": 2, "three": 2, "3": 2, "3rd": 2,
    "fourth": 3, "four": 3, "4": 3, "4th": 3,
    "fifth": 4, "five": 4, "5": 4, "5th": 4,
    "last": -1,
}  # fmt: skip
ORDINAL = re.compile(
    r"\b(?:the (first|second|third|fourth|fifth|last|1st|2nd|3rd|4th|5th)\b( one| option| place)?"
    r"|(?:number|option) (one|two|three|four|five|1|2|3|4|5)\b)"
)
PICK_MAX_WORDS = 8  # "take me to the second one please" picks; a longer sentence is its own


@dataclass(frozen=True)
class Turn:
    heard: str
    reply: str
    intent: str
    place: str = ""


@dataclass
class DialogueState:
    """One conversation's memory."""

    turns: deque[Turn] = field(default_factory=lambda: deque(maxlen=MAX_TURNS))
    place: Place | None = None  # the place last named, by the visitor or the robot
    offer: Place | None = None  # a place the robot offered to go to, waiting for a yes
    choices: tuple[Place, ...] = ()  # places offered as a choice, in the order said
    choice_intent: str = ""  # what a pick among them does: "navigate" or "where_is"
    topic: str = ""  # the last turn's intent
    last_at: float = 0.0

    def remember(self, heard: str, reply: str, intent: Intent) -> None:
        self.turns.append(Turn(heard, reply, intent.name, intent.place_name))
        self.topic = intent.name
        if intent.place is not None:
            self.place = intent.place

    def clear_choices(self) -> None:
        self.choices, self.choice_intent = (), ""


class Dialogues:
    """Dialogue state per session, bounded and expiring on the clock."""

    def __init__(self, idle_s: float = DIALOGUE_IDLE_S, max_sessions: int = MAX_SESSIONS) -> None:
        self.idle_s, self.max_sessions = idle_s, max_sessions
        self._states: OrderedDict[str, DialogueState] = OrderedDict()

    def get(self, session: str, now: float) -> DialogueState:
        """The session's state (a fresh one when new or idle too long)."""
        for key in [k for k, s in self._states.items() if now - s.last_at > self.idle_s]:
            del self._states[key]
        state = self._states.pop(session, None) or DialogueState()
        state.last_at = now
        self._states[session] = state  # most recent last
        while len(self._states) > self.max_sessions:
            self._states.popitem(last=False)
        return state

    def reset(self, session: str | None = None) -> None:
        """Forget one conversation, or all of them."""
        if session is None:
            self._states.clear()
        else:
            self._states.pop(session, None)

    def __len__(self) -> int:
        return len(self._states)

    def __contains__(self, session: object) -> bool:
        return session in self._states


def pick(t: str, choices: tuple[Place, ...]) -> Place | None:
    """The place "the second one" names among ``choices`` (None when it names none)."""
    if not choices or len(t.split()) > PICK_MAX_WORDS:
        return None
    m = ORDINAL.search(t)
    if m is None:
        return None
    index = _ORDINALS[m.group(1) or m.group(3)]
    return choices[index] if -len(choices) <= index < len(choices) else None


def _about(t: str, state: DialogueState, places: Places) -> Intent | None:
    """'What about the materials lab?': the last topic's question about another place."""
    m = ABOUT.match(t)
    hit = (exact_match(m.group(3), places) or fuzzy_match(m.group(3), places)) if m else None
    if hit is None:
        return None
    name = "describe_place" if state.topic == "describe_place" else "where_is"
    return Intent(name, hit.place, t, hit.how, (hit.place, *hit.tied) if hit.tied else ())


def _go_there(intent: Intent, state: DialogueState) -> Intent:
    """'Take me there' with no place of its own: the offer, else the place last named;
    with neither, a navigate without a place that says it was a reference."""
    target = state.offer or state.place
    if target is not None:
        return Intent("navigate", target, intent.slot, "context")
    return Intent("navigate", None, intent.slot, "reference")


def resolve(t: str, intent: Intent, state: DialogueState, places: Places) -> Intent:
    """What the classifier's ``intent`` means in this conversation: a pick among the
    choices, a yes or no to the offer, or "there" / "it" made into the place meant.

    ``t`` is the prepared utterance (:func:`intents.prepare`, wake words stripped).
    """
    chosen = pick(t, state.choices)
    if chosen is not None and intent.how != "exact":
        go = intent.name == "navigate" or state.choice_intent == "navigate"
        return Intent("navigate" if go else "where_is", chosen, t, "choice")
    if intent.place is not None:
        return intent
    if intent.name == "unknown":  # "no, I mean the restroom": a place named on its own
        hit = exact_match(t, places)
        if hit is not None:
            return Intent("where_is", hit.place, t, hit.how)
    short = len(t.split()) <= CONFIRM_MAX_WORDS
    if state.offer is not None and short and CONFIRM.match(t):
        return Intent("navigate", state.offer, t, "offer")
    if state.offer is not None and DECLINE.match(t):
        return Intent("goodbye", slot="no")
    if intent.name == "navigate" and REFERENCE.match(intent.slot):
        return _go_there(intent, state)
    if intent.name == "distance":
        return Intent("distance", state.place, t, "context")
    about = _about(t, state, places)
    if about is not None:
        return about
    if state.place is not None and REF_DESCRIBE.match(t):
        return Intent("describe_place", state.place, t, "context")
    if state.place is not None and REF_WHERE.match(t):
        return Intent("where_is", state.place, t, "context")
    return intent
