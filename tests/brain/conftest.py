"""Brain test helpers: small navigation and knowledge-base nodes served on a real Bus.

The fakes stand in for the navigator and the KB behind their bus interfaces (the same
actions and services the real nodes serve); they record what the brain asked for.
"""

from __future__ import annotations

import asyncio
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import pytest

from sage_robot.brain.robot import RobotLink
from sage_robot.brain.tools import ToolContext, ToolRegistry
from sage_robot.core import topics
from sage_robot.core.actions import GoalContext
from sage_robot.core.bus import Bus
from sage_robot.core.config import Settings
from sage_robot.core.msgs import Event, Text
from sage_robot.core.msgs.kb import Passage, SearchRequest, SearchResponse
from sage_robot.core.msgs.nav import (
    NavigateFeedback,
    NavigateGoal,
    NavigateResult,
    NavState,
    PlaceInfo,
    PlaceList,
    TourFeedback,
    TourGoal,
    TourResult,
    WhereAmI,
)
from sage_robot.core.paths import package_data
from sage_robot.core.places import Places, load_places

from ..support.waits import until as support_until

WAIT_S = 5.0  # every wait in these tests is bounded by this

CORPUS = [
    Passage(
        "The College of Engineering was founded in 1920. It moved into the Gleason Center in "
        "1998. Today it enrolls about six hundred students. See https://www.valpo.edu for more.",
        "talking_points.pdf",
        "History",
    ),
    Passage(
        "The clean room is a **class 1000** controlled environment. Students fabricate sensors "
        "and microchips there. Visitors watch through the window.",
        "talking_points.pdf",
        "Labs",
    ),
    Passage(
        "Valpo Robotics competes every spring. The team builds autonomous robots, including this tour robot.",
        "talking_points.pdf",
        "Clubs",
    ),
]


def seed_places() -> Places:
    return load_places(package_data("brain", "places.yaml"))


@dataclass
class FakeNav:
    """Serves navigate_to, tour, cancel, places and where-am-i like the navigator."""

    bus: Bus
    places: Places
    goals: list[str] = field(default_factory=list)
    tours: list[tuple[str, ...]] = field(default_factory=list)
    cancels: int = 0
    arrive: asyncio.Event = field(default_factory=asyncio.Event)
    fail_reason: str = ""
    position: tuple[float, float] = (15.5, 5.2)

    def serve(self) -> FakeNav:
        self.bus.actions.serve(topics.NAVIGATE_TO, self._navigate)
        self.bus.actions.serve(topics.TOUR, self._tour)
        self.bus.serve(topics.CANCEL_NAV, self._cancel)
        self.bus.serve(topics.PLACES, self._places)
        self.bus.serve(topics.WHERE_AM_I, self._where)
        return self

    async def _navigate(self, goal: NavigateGoal, ctx: GoalContext) -> NavigateResult:
        self.goals.append(goal.place)
        ctx.feedback(NavigateFeedback(NavState.DRIVING, goal.place, 12.0, 15.0))
        await self.arrive.wait()
        self.arrive.clear()
        if self.fail_reason:
            return NavigateResult(False, goal.place, self.fail_reason)
        self.bus.publish(topics.EVENTS, Event(0.0, "navigator", "arrived", "", {"place": goal.place}))
        return NavigateResult(True, goal.place)

    async def _tour(self, goal: TourGoal, ctx: GoalContext) -> TourResult:
        self.tours.append(goal.places)
        ctx.feedback(TourFeedback(0, goal.places[0], NavState.DRIVING))
        await asyncio.Event().wait()
        return TourResult((), True)

    async def _cancel(self, req: Any) -> Text:
        self.cancels += 1
        for name in (topics.NAVIGATE_TO, topics.TOUR):
            handle = self.bus.actions.active(name)
            if handle is not None:
                await handle.cancel()
        return Text("ok")

    async def _places(self, req: Any) -> PlaceList:
        return PlaceList(tuple(PlaceInfo(p.name, p.pose, p.description, p.aliases) for p in self.places))

    async def _where(self, req: Any) -> WhereAmI:
        place, dist = self.places.nearest(*self.position)
        from sage_robot.core.msgs import Pose2D

        return WhereAmI(Pose2D(*self.position, 0.0), place.name, dist, True)


@dataclass
class FakeKb:
    bus: Bus
    passages: list[Passage] = field(default_factory=lambda: list(CORPUS))
    queries: list[str] = field(default_factory=list)

    def serve(self) -> FakeKb:
        self.bus.serve(topics.KB_SEARCH, self._search)
        return self

    async def _search(self, req: SearchRequest) -> SearchResponse:
        """Rank by shared words (enough for a fake; the real KB embeds)."""
        self.queries.append(req.query)
        words = set(req.query.lower().split())
        ranked = sorted(self.passages, key=lambda p: -len(words & set(p.text.lower().split())))
        return SearchResponse(tuple(ranked[: req.top_k]))


@pytest.fixture
def places() -> Places:
    return seed_places()


@pytest.fixture
def bus() -> Bus:
    return Bus()


@pytest.fixture
def nav(bus: Bus, places: Places) -> FakeNav:
    return FakeNav(bus, places).serve()


@pytest.fixture
def kb(bus: Bus) -> FakeKb:
    return FakeKb(bus).serve()


@pytest.fixture(scope="session")
def kb_service(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Any]:
    """The real knowledge base (SQLite + all-MiniLM-L6-v2) with the shipped corpus, once per run."""
    from sage_robot.core.config.areas import KbSettings
    from sage_robot.kb.service import KbService

    service = KbService.from_settings(KbSettings(path=str(tmp_path_factory.mktemp("kb") / "kb.sqlite3")))
    service.ensure_corpus()
    yield service
    service.close()


@pytest.fixture
def real_kb(bus: Bus, kb_service: Any) -> Any:
    """``/kb/search`` served on the test's bus by the real KB (as KbNode serves it)."""

    async def search(req: SearchRequest) -> SearchResponse:
        return SearchResponse(tuple(await asyncio.to_thread(kb_service.search, req.query, req.top_k)))

    bus.serve(topics.KB_SEARCH, search)
    return kb_service


@pytest.fixture
def settings() -> Settings:
    return Settings()


def make_tools(bus: Bus, settings: Settings, fallback: Any = None) -> ToolRegistry:
    robot = RobotLink(bus, fallback)
    return ToolRegistry(ToolContext(robot, settings))


async def until(predicate: Any, timeout: float = WAIT_S) -> None:
    """Wait (bounded) until ``predicate()`` is true."""
    await support_until(predicate, timeout=timeout)
