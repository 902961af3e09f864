"""The offline brain: deterministic answers with no language model.

Each intent (:mod:`sage_robot.brain.intents`) has a handler; handlers act through the
same tools the model uses (so `sage ask --json` shows the same tool calls) and answer in
fixed, speakable lines. Knowledge questions are answered from the knowledge base: the
best passage that is really about the question (:mod:`sage_robot.brain.answers`),
trimmed to two or three sentences; when none is, an honest "I don't know".

Each conversation (``session``) has its dialogue state (:mod:`sage_robot.brain.dialogue`):
"yes", "take me there", "the second one", "what's there?" and "how far is it?" resolve
against it. When keywords find nothing, a sentence embedding (:mod:`sage_robot.brain.semantic`)
guesses the place, which is offered back, never driven to unasked; a weak guess gets a
clarifying question.
"""

from __future__ import annotations

import math
from collections.abc import Awaitable, Callable
from typing import Any

from sage_robot.brain.answers import Hit, best_hit, place_of, place_passage, repeats, trim
from sage_robot.brain.base import DEFAULT_SESSION, Brain, Say, Speaker, TurnResult
from sage_robot.brain.dialogue import Dialogues, DialogueState, resolve
from sage_robot.brain.intents import Intent, classify, prepare, strip_wake
from sage_robot.brain.matching import clean
from sage_robot.brain.phrases import (
    CAPABILITIES,
    DONT_KNOW,
    GOODBYES,
    GREETINGS,
    UNKNOWN,
    be,
    lower_first,
    pick,
    place_phrase,
    small_talk_line,
    spoken_ip,
    upper_first,
)
from sage_robot.brain.readiness import Refusal
from sage_robot.brain.robot import NavStatus
from sage_robot.brain.semantic import EmbedderSource, SemanticMatcher, intent_from_guess
from sage_robot.brain.speech import split_sentences
from sage_robot.brain.tools import ToolCall, ToolRegistry
from sage_robot.brain.tour_talk import TourTalk
from sage_robot.core.clock import Clock
from sage_robot.core.places import Place

KB_TOP_K = 3
DESCRIBE_KB_SENTENCES = 2  # sentences from the KB after a place's own description
NEAR_M = 3.0  # closer than this to a place is "at" it
PLACES_SPOKEN = 6  # places named in a list before "and more"
# A drive refused for these is answered with the refusal itself, a whole spoken sentence.
SPOKEN_REFUSALS = frozenset({Refusal.ESTOP.value, Refusal.BATTERY.value, Refusal.LOST.value})
ESTOP_STOPPED = "I am stopped: the emergency stop is on. An operator has to release it."
WHERE_TO = "Where would you like to go? You can name a place, or tell me what you are looking for."
CHOICES_SPOKEN = 4  # places named in a "which one?" question


def join_names(names: list[str]) -> str:
    if len(names) <= 1:
        return "".join(names)
    return ", ".join(names[:-1]) + " and " + names[-1]


def _target(motion: NavStatus) -> str:
    return place_phrase(motion.target) if motion.target else "a spot on my map"


def _moving_line(motion: NavStatus) -> str:
    """What a robot on its way says it is doing, from the navigator's state."""
    where = _target(motion)
    state = motion.state
    if state == "waiting_for_people":
        return f"I am waiting for people to make room, on the way to {where}."
    if state == "recovering":
        return f"I am finding a way around something in my path, on the way to {where}."
    if state == "lost":
        return f"I have lost track of where I am, so I am looking around before going on to {where}."
    dist = motion.distance_remaining_m
    togo = f", about {round(dist)} meters to go" if dist >= 1 else ""
    if motion.touring:
        return f"We are on a tour, heading to {where}{togo}."
    return f"I am on my way to {where}{togo}."


Handler = Callable[[Intent, str], Awaitable[str]]


class OfflineBrain(Brain):
    """Rules, tools and the knowledge base; no model, no network."""

    kind = "offline"

    def __init__(
        self,
        tools: ToolRegistry,
        robot_name: str = "SAGE Jarvis",
        clock: Clock | None = None,
        embedder: EmbedderSource | None = None,
    ) -> None:
        self.tools = tools
        self.robot = tools.ctx.robot
        self.name = robot_name
        self.clock = clock or self.robot.bus.clock
        self.dialogues = Dialogues()
        self.semantic = SemanticMatcher(embedder or (lambda: None))
        self._state = DialogueState()  # the conversation of the turn being answered
        self._calls: list[ToolCall] = []
        self.tour_talk = TourTalk(self._tool)  # planned tours: said, started on a "yes", controlled
        self._handlers: dict[str, Handler] = {
            "greeting": self._greeting,
            "goodbye": self._goodbye,
            "small_talk": self._small_talk,
            "capabilities": self._capabilities,
            "navigate": self._navigate,
            "where_is": self._where_is,
            "cancel": self._cancel,
            "where_am_i": self._where_am_i,
            "status": self._status,
            "battery": self._battery,
            "ip_address": self._ip,
            "tour": self._tour,
            "tour_control": self.tour_talk.control,
            "list_places": self._list_places,
            "describe_place": self._describe,
            "distance": self._distance,
            "suggest": self._suggest,
            "clarify": self._clarify,
            "question": self._question,
            "unknown": self._unknown,
        }

    def reset(self, session: str | None = None) -> None:
        self.dialogues.reset(session)

    async def classify(self, text: str) -> Intent:
        return classify(text, await self.robot.places())

    async def respond(self, text: str, say: Say | None = None, session: str = DEFAULT_SESSION) -> TurnResult:
        result = TurnResult(brain=self.kind)
        speaker = Speaker(say, result)
        self._calls = result.tool_calls
        state = self._state = self.dialogues.get(session, self.clock.now())
        intent = self.tour_talk.follow_up(text, session) or await self.understand(text, state)
        result.intent = intent.name
        state.offer = None  # an offer or a choice stands for one turn: the handler makes it again
        state.clear_choices()
        reply = await self._handlers[intent.name](intent, text)
        state.remember(text, reply, intent)
        for sentence in split_sentences(reply):
            speaker(sentence)
        return speaker.finish()

    async def understand(self, text: str, state: DialogueState) -> Intent:
        """The intent of ``text`` in this conversation: rules, then the dialogue state,
        then the semantic guess when neither found what the visitor meant."""
        places = await self.robot.places()
        t = strip_wake(prepare(text))
        intent = resolve(t, classify(text, places), state, places)
        if intent.choices:
            return Intent("clarify", intent.place, intent.name, intent.how, intent.choices)
        wants_place = intent.name == "navigate" and intent.place is None
        if intent.name != "unknown" and not wants_place:  # questions go to the KB, which knows more
            return intent
        guess = await self.semantic.guess(text, places, self.clock)
        return intent_from_guess(intent, guess)

    async def react(self, prompt: str, fallback: str, say: Say | None = None) -> TurnResult:
        result = TurnResult(brain=self.kind, intent="event")
        speaker = Speaker(say, result)
        for sentence in split_sentences(fallback):
            speaker(sentence)
        return speaker.finish()

    async def _tool(self, name: str, args: dict[str, Any] | None = None) -> ToolCall:
        call = await self.tools.call(name, args or {})
        self._calls.append(call)
        return call

    # ------------------------------------------------------------ handlers
    async def _greeting(self, intent: Intent, text: str) -> str:
        return pick(GREETINGS, text).format(name=self.name)

    async def _goodbye(self, intent: Intent, text: str) -> str:
        if intent.slot == "no":
            return "No problem. Let me know if you would like to go anywhere."
        return pick(GOODBYES, text)

    async def _small_talk(self, intent: Intent, text: str) -> str:
        return small_talk_line(text, self.name)

    async def _capabilities(self, intent: Intent, text: str) -> str:
        return CAPABILITIES

    async def _navigate(self, intent: Intent, text: str) -> str:
        if intent.place is None:
            return WHERE_TO if intent.how == "reference" else await self._unknown_place(intent.slot)
        call = await self._tool("set_goal", {"location": intent.place.name})
        if not call.result.ok:
            if call.result.data.get("refused") in SPOKEN_REFUSALS:
                return call.result.error
            return f"Sorry, I can not take you to {place_phrase(intent.place)}: {call.result.error}."
        return f"Sure, follow me to {place_phrase(intent.place)}!"  # only once the goal was taken

    def _offer_to_go(self, place: Place, offer: str) -> str:
        """``offer`` (and remember it for a "yes"), or why the robot can not go now."""
        refused = self.robot.readiness().refuse_drive(place.name)
        if refused is None:
            self._state.offer = place
            return offer
        return refused[1]

    async def _unknown_place(self, slot: str) -> str:
        places = await self.robot.places()
        names = [place_phrase(p) for p in places][:PLACES_SPOKEN]
        slot = slot.removeprefix("to ")  # "take me to the moon": the slot is "to the moon"
        what = f" called {slot}" if slot and len(slot) < 40 else " by that name"
        if not names:
            return f"I do not know a place{what}, and I have no map of places loaded right now."
        more = " and more" if len(places) > PLACES_SPOKEN else ""
        return f"I do not know a place{what}. I can take you to {join_names(names)}{more}."

    async def _where_is(self, intent: Intent, text: str) -> str:
        assert intent.place is not None
        what = f": {lower_first(intent.place.description.rstrip('.'))}" if intent.place.description else ""
        offer = self._offer_to_go(intent.place, "Shall I take you there?")
        return f"{upper_first(place_phrase(intent.place))} {be(intent.place)} on my map{what}. {offer}"

    async def _cancel(self, intent: Intent, text: str) -> str:
        call = await self._tool("cancel_goal")
        if not call.result.ok:
            return f"I could not stop: {call.result.error}."
        if call.result.data.get("stopped"):
            return "Okay, I have stopped."
        return "Okay. I was not going anywhere anyway."

    async def _where_am_i(self, intent: Intent, text: str) -> str:
        call = await self._tool("where_am_i")
        if not call.result.ok:
            return f"I am not sure where we are: {call.result.error}."
        d = call.result.data
        place = place_phrase(d["nearest_place"])
        if not d.get("localized", True):
            return f"I am not completely sure, but I think we are near {place}."
        if d["distance_m"] <= NEAR_M:
            return f"We are at {place}."
        return f"We are about {round(d['distance_m'])} meters from {place}."

    async def _status(self, intent: Intent, text: str) -> str:
        """What the robot is doing: the e-stop first, then the drive, then what holds it."""
        ready, motion = self.robot.readiness(), self.robot.motion()
        if ready.estop:
            was = f" I was on my way to {_target(motion)}." if motion.navigating else ""
            return ESTOP_STOPPED + was
        if motion.navigating:
            return _moving_line(motion)
        if ready.lost:
            return "I am standing still, because I have lost track of where I am on my map. " \
                   "An operator can set my position."
        refused = ready.refuse_drive("")
        if refused is not None and refused[0] is Refusal.BATTERY:
            return f"I am standing still. {refused[1]}"
        return "I am standing still, ready to go. Where would you like to go?"

    async def _battery(self, intent: Intent, text: str) -> str:
        call = await self._tool("battery_status")
        if not call.result.ok:
            return "I can not read my battery right now."
        d = call.result.data
        charging = " and charging" if d["status"] in ("charging", "full") else ""
        if d["percent"] is None:
            return f"My battery reads {d['voltage']} volts{charging}."
        return f"My battery is at {d['percent']} percent{charging}."

    async def _ip(self, intent: Intent, text: str) -> str:
        call = await self._tool("get_ip_address")
        if not call.result.ok:
            return "I do not have a network address right now."
        parts = [f"{spoken_ip(a[0])} on {name}" for name, a in call.result.data["interfaces"].items()]
        return f"My address is {join_names(parts[:3])}."

    async def _tour(self, intent: Intent, text: str) -> str:
        if intent.how in ("plan", "consent"):  # a tour planned for the visitor (brain/tour_talk.py)
            refused = self.robot.readiness().refuse_tour()
            return await self.tour_talk.handle(intent, text, refused[1] if refused else "")
        args = {"theme": intent.slot} if intent.slot else {}
        call = await self._tool("start_tour", args)
        if not call.result.ok:
            if call.result.data.get("refused") in SPOKEN_REFUSALS:
                return call.result.error
            return f"Sorry, I can not start a tour: {call.result.error}."
        stops = call.result.data["stops"]
        return (
            f"Wonderful, let us go! The tour has {len(stops)} stops, "
            f"starting with {place_phrase(stops[0])}. Follow me!"
        )

    async def _list_places(self, intent: Intent, text: str) -> str:
        await self._tool("list_places")
        places = await self.robot.places()
        if not len(places):
            return "I have no places loaded right now."
        shown = [p for p in places if p.name != "DOCKING_STATION"]
        self._state.choices, self._state.choice_intent = tuple(shown), "navigate"
        names = join_names([place_phrase(p) for p in shown])
        return f"I can take you to {names}. Where would you like to go?"

    async def _describe(self, intent: Intent, text: str) -> str:
        """The place's description, then one or two sentences about it from the KB (else
        its talking points), without saying the same thing twice; then an offer to go."""
        place = intent.place
        assert place is not None
        call = await self._tool("describe_place", {"name": place.name})
        d = call.result.data if call.result.ok else {}
        desc = str(d.get("description") or place.description or "one of the places on my tour")
        said = f"Here is what I know about {place_phrase(place)}: {lower_first(desc.rstrip('.'))}."
        more = await self._about_place(place) or str(d.get("talking_points") or "")
        for sentence in split_sentences(more)[:DESCRIBE_KB_SENTENCES]:
            if not repeats(sentence, said):
                said += " " + sentence
        return said + " " + self._offer_to_go(place, "Would you like to go there?")

    async def _about_place(self, place: Place) -> str:
        """One or two sentences about ``place`` from the knowledge base ('' when none)."""
        spoken = place.aliases[0] if place.aliases else clean(place.name)
        query = f"What is the {spoken}? {place.description}".strip()
        call = await self._tool("kb_search", {"query": query, "top_k": KB_TOP_K})
        if not call.result.ok:
            return ""
        hits = [Hit.from_tool(p) for p in call.result.data["passages"]]
        names = {clean(n) for n in (*place.spoken_names(), place.name)}
        found = place_passage(query, hits, names)
        return trim(found.text, sentences=DESCRIBE_KB_SENTENCES) if found else ""

    async def _question(self, intent: Intent, text: str) -> str:
        call = await self._tool("kb_search", {"query": text, "top_k": KB_TOP_K})
        if not call.result.ok:
            return f"I can not look that up, because {lower_first(call.result.error)}."
        found = best_hit(text, [Hit.from_tool(p) for p in call.result.data["passages"]])
        if found is None:
            return DONT_KNOW
        about = place_of(found, await self.robot.places())
        if about is not None:  # the answer came from a place's own page: "take me there" goes there
            self._state.place = about
        return trim(found.text, text)

    async def _unknown(self, intent: Intent, text: str) -> str:
        return UNKNOWN

    async def _suggest(self, intent: Intent, text: str) -> str:
        """A place the semantic guess found: said back as a question, never driven to unasked."""
        assert intent.place is not None
        what = f", {lower_first(intent.place.description.rstrip('.'))}" if intent.place.description else ""
        offer = self._offer_to_go(intent.place, "Shall I take you there?")
        return f"Do you mean {place_phrase(intent.place)}{what}? {offer}"

    async def _clarify(self, intent: Intent, text: str) -> str:
        """Which of several places, or where to at all."""
        if not intent.choices:
            return WHERE_TO
        shown = intent.choices[:CHOICES_SPOKEN]
        self._state.choices = shown
        self._state.choice_intent = "navigate" if intent.slot == "navigate" else "where_is"
        names = [place_phrase(p) for p in shown]
        more = len(intent.choices) - len(shown)
        if more:
            return f"There are {len(intent.choices)} of those: {', '.join(names)} and {more} more. Which one?"
        return f"Which one do you mean: {', '.join(names[:-1])} or {names[-1]}?"

    async def _distance(self, intent: Intent, text: str) -> str:
        """How far a place is, in a straight line from the place we are nearest to."""
        place = intent.place
        if place is None:
            return "How far is which place? Tell me where you would like to go."
        call = await self._tool("where_am_i")
        offer = self._offer_to_go(place, "Shall I take you there?")
        if not call.result.ok:
            how_far = f"how far {place_phrase(place)} {be(place)}"
            return f"I am not sure where we are right now, so I can not say {how_far}. {offer}"
        d = call.result.data
        places = await self.robot.places()
        if d["nearest_place"] == place.name and d["distance_m"] <= NEAR_M:
            return f"We are right at {place_phrase(place)}."
        here = places.get(d["nearest_place"]) if d["nearest_place"] in places else None
        if here is None:
            return f"I can not tell how far {place_phrase(place)} {be(place)} from here. {offer}"
        meters = math.hypot(place.pose.x - here.pose.x, place.pose.y - here.pose.y) + d["distance_m"]
        return (
            f"{upper_first(place_phrase(place))} {be(place)} about {round(meters)} meters from here, "
            f"as the crow flies. {offer}"
        )
