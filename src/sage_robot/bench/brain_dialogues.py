"""Multi-turn dialogues for the offline brain, scored turn by turn (`sage bench brain`).

``data/brain/dialogues_dev.yaml`` is used while developing (tests, tuning);
``dialogues_heldout.yaml`` was written once, from the visitor's point of view, before the
dialogue code was tuned, and only this benchmark reads it. A turn is right when the first
tool call it makes is the expected one with the expected place ("set_goal GUELLY_DELLY",
"describe_place CLEAN_ROOM", "where_am_i", "none"). A *wrong navigation* is a ``set_goal``
where none was expected, or to another place.

The brain is the real offline brain, with the real sentence embedder (all-MiniLM-L6-v2,
from its installed package) for the semantic fallback, on a real bus. Navigation is a
small stand-in serving the real ``navigate_to`` action, ``/nav/cancel`` and
``/nav/where_am_i`` (goals are taken and keep running; the robot stands at the dock). The
knowledge base is the real one (SQLite, the shipped corpus) served on ``/kb/search``, so
an answer from a place's own page makes that place the one "take me there" means. Each
dialogue is its own session.
"""

from __future__ import annotations

import asyncio
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from sage_robot.brain.base import TurnResult
from sage_robot.brain.offline import OfflineBrain
from sage_robot.brain.robot import RobotLink
from sage_robot.brain.semantic import EmbedderSource
from sage_robot.brain.tools import ToolContext, ToolRegistry
from sage_robot.core import topics
from sage_robot.core.actions import GoalContext
from sage_robot.core.bus import Bus
from sage_robot.core.config import Settings
from sage_robot.core.errors import ConfigError
from sage_robot.core.msgs import Pose2D, Text
from sage_robot.core.msgs.kb import SearchRequest, SearchResponse
from sage_robot.core.msgs.nav import NavigateFeedback, NavigateGoal, NavigateResult, NavState, WhereAmI
from sage_robot.core.paths import package_data
from sage_robot.core.places import Places, load_places

STANDS_AT = "DOCKING_STATION"  # where the stand-in navigation says the robot is
TURN_TIMEOUT_S = 30.0  # longest one turn may take (the embedder loads on the first that needs it)
FEEDBACK_DISTANCE_M = 10.0  # what the stand-in navigation reports as left to drive


@dataclass(frozen=True)
class Dialogue:
    name: str
    turns: tuple[tuple[str, tuple[str, ...]], ...]  # (what the visitor says, accepted outcomes)


def load_dialogues(path: Path) -> list[Dialogue]:
    """The dialogues of one file; a malformed one is a ConfigError naming it."""
    data = yaml.safe_load(path.read_text())
    out = []
    for i, d in enumerate((data or {}).get("dialogues") or []):
        try:
            turns = tuple((str(t[0]), tuple(str(t[1]).split("|"))) for t in d["turns"])
            out.append(Dialogue(str(d["name"]), turns))
        except (KeyError, IndexError, TypeError) as exc:
            raise ConfigError(f"{path.name}: dialogue {i + 1} is malformed ({exc})") from exc
    return out


def outcome(result: TurnResult) -> str:
    """The first tool call of a turn with its place ("set_goal CLEAN_ROOM"), or "none"."""
    if not result.tool_calls:
        return "none"
    call = result.tool_calls[0]
    args = call.arguments if isinstance(call.arguments, dict) else {}
    arg = str(args.get("location") or args.get("name") or "")
    if call.name == "set_goal" and call.result.ok:
        arg = call.result.data.get("place", arg)
    return f"{call.name} {arg}".strip()


@dataclass
class StandInNav:
    """Takes navigation goals and keeps them running; the robot stands at one place."""

    bus: Bus
    places: Places
    goals: list[str] = field(default_factory=list)

    def serve(self) -> StandInNav:
        self.bus.actions.serve(topics.NAVIGATE_TO, self._navigate, policy="preempt")
        self.bus.serve(topics.CANCEL_NAV, self._cancel)
        self.bus.serve(topics.WHERE_AM_I, self._where)
        return self

    async def _navigate(self, goal: NavigateGoal, ctx: GoalContext) -> NavigateResult:
        self.goals.append(goal.place)
        ctx.feedback(NavigateFeedback(NavState.DRIVING, goal.place, FEEDBACK_DISTANCE_M, FEEDBACK_DISTANCE_M))
        await asyncio.Event().wait()  # until cancelled or preempted
        return NavigateResult(True, goal.place)

    async def _cancel(self, req: Any) -> Text:
        handle = self.bus.actions.active(topics.NAVIGATE_TO)
        if handle is not None:
            await handle.cancel()
        return Text("ok")

    async def _where(self, req: Any) -> WhereAmI:
        here = self.places.get(STANDS_AT)
        return WhereAmI(Pose2D(here.pose.x, here.pose.y, 0.0), here.name, 0.0, True)


@dataclass
class Score:
    turns: int = 0
    right: int = 0
    wrong_navigations: int = 0
    misses: list[str] = field(default_factory=list)

    def as_dict(self, show_misses: bool) -> dict[str, Any]:
        out: dict[str, Any] = {
            "turns": self.turns,
            "turns_right": self.right,
            "accuracy": round(self.right / max(1, self.turns), 3),
            "wrong_navigations": self.wrong_navigations,
        }
        if show_misses:
            out["misses"] = self.misses
        return out


def _wrong_navigation(got: str, expected: tuple[str, ...]) -> bool:
    return got.startswith("set_goal") and got not in expected


async def score_dialogues(
    dialogues: list[Dialogue], embedder: EmbedderSource | None, kb: Any = None
) -> Score:
    """Every dialogue through a fresh session of one offline brain; ``kb`` (a
    ``KbService``, or None for none) answers ``/kb/search``."""
    bus = Bus()
    if kb is not None:

        async def search(req: SearchRequest) -> SearchResponse:
            return SearchResponse(tuple(await bus.clock.offload(kb.search, req.query, req.top_k)))

        bus.serve(topics.KB_SEARCH, search)
    places = load_places(package_data("brain", "places.yaml"))
    StandInNav(bus, places).serve()
    robot = RobotLink(bus, package_data("brain", "places.yaml"))
    brain = OfflineBrain(ToolRegistry(ToolContext(robot, Settings())), clock=bus.clock, embedder=embedder)
    score = Score()
    try:
        for d in dialogues:
            for i, (said, expected) in enumerate(d.turns):
                result = await asyncio.wait_for(brain.respond(said, session=d.name), TURN_TIMEOUT_S)
                got = outcome(result)
                score.turns += 1
                score.right += got in expected
                score.wrong_navigations += _wrong_navigation(got, expected)
                if got not in expected:
                    want = "|".join(expected)
                    score.misses.append(f"{d.name} #{i + 1} {said!r}: got {got!r}, want {want!r}")
            await robot.cancel()
    finally:
        await robot.close()
    return score


def run_dialogues(embedder: EmbedderSource | None) -> dict[str, Any]:
    """Scores of the development set (with its misses) and the held-out set (numbers only)."""
    import tempfile

    from sage_robot.core.config.areas import KbSettings
    from sage_robot.kb.service import KbService

    out: dict[str, Any] = {}
    with tempfile.TemporaryDirectory() as tmp:
        kb = KbService.from_settings(KbSettings(path=f"{tmp}/kb.sqlite3"))
        try:
            kb.ensure_corpus()
            for which in ("dev", "heldout"):
                dialogues = load_dialogues(package_data("brain", f"dialogues_{which}.yaml"))
                score = asyncio.run(score_dialogues(dialogues, embedder, kb))
                out[which] = {"dialogues": len(dialogues), **score.as_dict(show_misses=which == "dev")}
        finally:
            kb.close()
    return out
