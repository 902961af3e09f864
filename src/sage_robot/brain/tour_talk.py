"""The offline brain's side of planned tours: the plan said back, started on a "yes", and
the running tour paused, skipped, resumed or stopped by voice.

"I have ten minutes, show me the labs" → ``plan_tour`` → "I can show you ...: 4 stops, about
9 minutes. Shall we start?" and the plan is kept for that conversation (one turn, like any
offer); "yes" → ``start_tour`` with the plan's places, in its order. The same two tools an
LLM calls. "Pause the tour", "skip this one", "resume", "stop the tour" → ``tour_control``.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from typing import Any

from sage_robot.brain.intents import CONFIRM, DECLINE, Intent, prepare, strip_wake
from sage_robot.brain.phrases import place_phrase
from sage_robot.brain.readiness import Refusal
from sage_robot.brain.tools import ToolCall
from sage_robot.brain.tours import SECONDS_PER_MINUTE, minutes_phrase, parse_budget_s

CallTool = Callable[[str, dict[str, Any]], Awaitable[ToolCall]]
CONSENT_MAX_WORDS = 5  # "yes let us go please" consents; a longer sentence is a new request
PLAN_SPOKEN = 5  # stops named in a spoken plan before "and N more"
SPOKEN_REFUSALS = frozenset({Refusal.ESTOP.value, Refusal.BATTERY.value, Refusal.LOST.value})
CONTROL_LINES = {
    "pause": "Sure, I will wait here. Say resume when you want to go on.",
    "resume": "Let us go on!",
    "skip": "All right, we skip that one.",
    "stop": "All right, the tour ends here. Thank you for coming along!",
}


def join(names: list[str]) -> str:
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]


def spoken_plan(data: dict[str, Any]) -> str:
    """A plan tool result in one sentence: "I can show you A, B and C: 3 stops, about 7 minutes."."""
    names = [place_phrase(n) for n in data["stops"]]
    shown = names
    if len(names) > PLAN_SPOKEN:
        shown = [*names[: PLAN_SPOKEN - 1], f"{len(names) - PLAN_SPOKEN + 1} more"]
    stops = "one stop" if len(names) == 1 else f"{len(names)} stops"
    return f"I can show you {join(shown)}: {stops}, about {minutes_phrase(data['estimate_s'])}."


class TourTalk:
    """Planned tours in the offline brain's conversations (one pending plan per session)."""

    def __init__(self, call: CallTool) -> None:
        self.call = call
        self.offers: dict[str, list[str]] = {}  # session -> the planned stops awaiting a "yes"
        self.session = ""

    def follow_up(self, text: str, session: str) -> Intent | None:
        """A "yes" (or "no") to the plan offered in this conversation's last turn; any other
        words drop the offer and go to the rules."""
        self.session = session
        offer = self.offers.pop(session, None)
        if offer is None:
            return None
        t = strip_wake(prepare(text))
        if CONFIRM.match(t) and len(t.split()) <= CONSENT_MAX_WORDS:
            self.offers[session] = offer  # taken by :meth:`handle` this turn
            return Intent("tour", slot=" ".join(offer), how="consent")
        if DECLINE.match(t):
            return Intent("goodbye", slot="no")
        return None

    async def handle(self, intent: Intent, text: str, refusal: str) -> str:
        """``how == "plan"``: plan and offer (``refusal``: why no tour can start now, else "");
        ``how == "consent"``: start the offered plan."""
        if intent.how == "consent":
            return await self._start(self.offers.pop(self.session, []))
        args: dict[str, Any] = {"interests": text}
        budget = parse_budget_s(text)
        if budget is not None:
            args["minutes"] = budget / SECONDS_PER_MINUTE
        call = await self.call("plan_tour", args)
        if not call.result.ok:
            return f"Sorry, I can not plan that tour: {call.result.error.rstrip('.')}."
        said = spoken_plan(call.result.data)
        if refusal:
            return f"{said} {refusal}"
        self.offers[self.session] = list(call.result.data["stops"])
        return f"{said} Shall we start?"

    async def _start(self, stops: list[str]) -> str:
        call = await self.call("start_tour", {"places": stops})
        if not call.result.ok:
            if call.result.data.get("refused") in SPOKEN_REFUSALS:
                return call.result.error
            return f"Sorry, I can not start the tour: {call.result.error.rstrip('.')}."
        first = call.result.data["stops"][0]
        return f"Wonderful, let us go! First, {place_phrase(first)}. Follow me!"

    async def control(self, intent: Intent, text: str) -> str:
        call = await self.call("tour_control", {"command": intent.slot})
        if call.result.ok:
            return CONTROL_LINES[intent.slot]
        if call.result.data.get("refused") in SPOKEN_REFUSALS:
            return call.result.error
        error = call.result.error.rstrip(".")
        return f"{error[:1].upper()}{error[1:]}."
