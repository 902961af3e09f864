"""The ``brain`` node: serves the ``converse`` action and turns robot events into speech.

- Action :data:`topics.CONVERSE`: goal ``Text`` (what the visitor said) → feedback ``Text``
  per sentence as it is ready → result ``Text`` (the whole reply). Cancelling the goal
  (barge-in) stops generation at once.
- :data:`topics.EVENTS`: ``arrived`` → a short welcome for the place; ``blocked_by_people``
  → "Excuse me, could I get by?"; ``lost`` → asks for help; ``battery_low`` /
  ``battery_critical`` → tells the visitor it must return to its dock. Each sentence is
  published as ``Text`` on :data:`topics.SAY`; a navigation goal the brain started that
  fails is announced the same way.
- The conversation is forgotten after ``llm.idle_reset_s`` without a turn. A goal may be
  an :class:`~sage_robot.brain.base.Utterance` naming its session: each session keeps its
  own dialogue state (``Text`` goals are the robot's own session).
- The semantic fallback uses the sentence embedder in ``ctx.resources[SENTENCE_EMBEDDER]``
  when one is there (looked up at each turn that needs it), else keywords only.
"""

from __future__ import annotations

import asyncio
from typing import Any

from sage_robot.brain.base import DEFAULT_SESSION, Brain, TurnResult, Utterance
from sage_robot.brain.offline import OfflineBrain
from sage_robot.brain.phrases import EVENT_LINES, UNKNOWN, place_phrase, upper_first, welcome
from sage_robot.brain.robot import RobotLink
from sage_robot.brain.semantic import EmbedderSource
from sage_robot.brain.tools import ToolContext, ToolRegistry
from sage_robot.core import topics
from sage_robot.core.actions import GoalContext
from sage_robot.core.clock import Clock
from sage_robot.core.config import Settings
from sage_robot.core.embedding import SENTENCE_EMBEDDER
from sage_robot.core.msgs import Event, Text
from sage_robot.core.node import Node
from sage_robot.core.paths import waypoints_yaml

EVENT_TURN_TIMEOUT_S = 20.0  # longest an arrival welcome may take before it is dropped


def make_brain(
    settings: Settings, robot: RobotLink, clock: Clock, embedder: EmbedderSource | None = None
) -> Brain:
    """The configured brain: the LLM agent when ``llm.base_url`` is set, else offline;
    ``embedder`` gives the offline brain its semantic fallback."""
    tools = ToolRegistry(ToolContext(robot, settings))
    if settings.llm.base_url:
        from sage_robot.brain.llm import LlmBrain

        brain = LlmBrain(settings, tools, clock)
        if embedder is not None:
            brain.offline = OfflineBrain(tools, settings.robot.name, clock, embedder)
        return brain
    return OfflineBrain(tools, settings.robot.name, clock, embedder)


class BrainNode(Node):
    name = "brain"

    async def setup(self) -> None:
        self.robot = RobotLink(self.bus, waypoints_yaml(self.settings), self.settings.battery)
        self.robot.on_failure = self._nav_failed
        self.brain = make_brain(
            self.settings, self.robot, self.clock, lambda: self.ctx.resources.get(SENTENCE_EMBEDDER)
        )
        self._lock = asyncio.Lock()
        self._last_turn = self.clock.now()
        self.turns = 0
        self.events_spoken = 0
        for topic, msg_type, callback in self.robot.subscriptions():  # battery, e-stop, nav, localization
            self.subscribe(topic, msg_type, callback, maxsize=1)
        self.subscribe(topics.EVENTS, Event, self._on_event, maxsize=20)
        # One conversation: visitors' questions (voice, /talk, typed) are answered in turn.
        self.bus.actions.serve(topics.CONVERSE, self._converse, policy="queue")

    async def teardown(self) -> None:
        self.bus.actions.unserve(topics.CONVERSE)
        if hasattr(self, "robot"):
            await self.robot.close()

    def stats(self) -> dict[str, Any]:
        brain = getattr(self, "brain", None)  # None before setup
        return {"brain": brain.kind if brain else "", "turns": getattr(self, "turns", 0)}

    def _idle_check(self) -> None:
        now = self.clock.now()
        if now - self._last_turn > self.settings.llm.idle_reset_s:
            self.brain.reset()
        self._last_turn = now

    async def _converse(self, goal: Text | Utterance, ctx: GoalContext) -> Text:
        heard, session = (goal.data, DEFAULT_SESSION) if isinstance(goal, Text) else (goal.text, goal.session)
        if not heard.strip():  # an empty transcript: nothing to think about
            ctx.feedback(Text(UNKNOWN))
            return Text(UNKNOWN)
        async with self._lock:
            self._idle_check()
            result = await self.brain.respond(heard, lambda s: ctx.feedback(Text(s)), session)
            self.turns += 1
            self.log.debug("turn", heard=heard, reply=result.reply, brain=result.brain, session=session)
            return Text(result.reply)

    def _say(self, sentence: str) -> None:
        self.bus.publish(topics.SAY, Text(sentence))

    def _nav_failed(self, place: str, reason: str) -> None:
        self._say(f"Sorry, I could not get to {place_phrase(place)}. {upper_first(reason.rstrip('.'))}.")

    async def _on_event(self, event: Event) -> None:
        self.robot.on_event(event)
        if event.kind == "arrived":
            await self._welcome(event.data.get("place", "") or event.message)
        elif event.kind in EVENT_LINES:
            self._say(EVENT_LINES[event.kind])
            self.events_spoken += 1

    async def _welcome(self, name: str) -> None:
        places = await self.robot.places()
        place = places.get(name) if name in places else None
        fallback = welcome(place, name)
        prompt = f"You have just arrived at {name}. Welcome the visitor there in one or two sentences."
        async with self._lock:
            self._last_turn = self.clock.now()
            try:
                result: TurnResult = await self.clock.wait_for(
                    self.brain.react(prompt, fallback, self._say), EVENT_TURN_TIMEOUT_S
                )
            except asyncio.TimeoutError:
                self.log.warning("arrival welcome timed out", place=name)
                return
        self.events_spoken += 1
        self.log.info("welcome", place=name, reply=result.reply)
