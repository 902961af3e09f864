"""The brain's view of the robot: navigation, places, battery, e-stop, localization and
the knowledge base, reached only through the bus (actions and services other nodes serve).

Every method returns a value: when a service or action is not there (its node is not
running yet) the answer says so in words a person (or a model) can use; nothing raises
for an expected failure. Services that take no arguments are called with ``Text("")``.

A drive or a tour starts only when :mod:`sage_robot.brain.readiness` allows it (e-stop,
battery, localization) and counts as started only when navigation took the goal: it did
not abort it at once (unknown place, no pose) within ``ACCEPT_WAIT_S``.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sage_robot.brain.readiness import (
    LOST_CONFIRM_S,
    NAV_DOWN_LINE,
    TOUR_DOWN_LINE,
    Readiness,
    Refusal,
)
from sage_robot.core import topics
from sage_robot.core.actions import GoalHandle, GoalStatus, GoalTimeout
from sage_robot.core.bus import Bus
from sage_robot.core.config.robot import BatterySettings
from sage_robot.core.errors import ConfigError, ServiceError
from sage_robot.core.msgs import BatteryState, EStopState, Event, Text
from sage_robot.core.msgs.kb import Passage, SearchRequest, SearchResponse
from sage_robot.core.msgs.nav import (
    LocalizationHealth,
    NavigateFeedback,
    NavigateGoal,
    NavState,
    PlaceList,
    TourFeedback,
    TourGoal,
    WhereAmI,
)
from sage_robot.core.places import Place, Places, load_places

PLACES_TTL_S = 30.0  # how long a fetched place list is trusted before asking again
SERVICE_TIMEOUT_S = 3.0  # nav and kb service calls from a conversation turn
KB_TIMEOUT_S = 8.0  # a knowledge-base search may embed the query first
ACCEPT_WAIT_S = 0.5  # wall time a new goal has to show feedback or fail before it counts as taken
ACCEPT_POLL_S = 0.01
HEALTH_STALE_S = 5.0  # a localization health older than this (bus clock) no longer says "lost"

_log = logging.getLogger("sage.brain")


@dataclass(frozen=True)
class Outcome:
    """An expected result: ``ok`` with data, or not ok with a reason for a person."""

    ok: bool
    reason: str = ""
    data: Any = None
    refused: Refusal | None = None  # set when a drive was not started, and why


@dataclass
class NavStatus:
    """What the robot is doing, for the system prompt and the tools."""

    navigating: bool = False
    target: str = ""
    state: str = "idle"
    distance_remaining_m: float = 0.0
    touring: bool = False

    def describe(self) -> str:
        if not self.navigating:
            return "idle, standing still"
        what = "on a tour, heading" if self.touring else "navigating"
        dist = f", {self.distance_remaining_m:.0f} meters to go" if self.distance_remaining_m else ""
        return f"{what} to {self.target or 'a point on the map'} ({self.state}{dist})"

    @classmethod
    def from_navigator(cls, fb: NavigateFeedback) -> NavStatus:
        """The navigator's own state (``/nav/state``): a goal someone else sent."""
        return cls(True, fb.place, fb.state.value, fb.distance_remaining_m)


class RobotLink:
    """Bus-facing helper shared by the tools, the prompt and the offline brain. Feed it
    with :meth:`subscriptions` (the brain node subscribes each)."""

    def __init__(
        self, bus: Bus, fallback_places: Path | None = None, battery: BatterySettings | None = None
    ) -> None:
        self.bus = bus
        self.fallback_places = fallback_places
        levels = battery or BatterySettings()
        self.battery_critical, self.battery_low = levels.critical_fraction, levels.warn_fraction
        self.battery: BatteryState | None = None
        self.estop: EStopState | None = None
        self.nav_state: NavigateFeedback | None = None  # the navigator's, whoever sent the goal
        self.health: LocalizationHealth | None = None
        self._health_at = -math.inf
        self._lost_since: float | None = None
        self.nav = NavStatus()
        self._places: Places | None = None
        self._places_at = -1e18
        self._goal: GoalHandle | None = None
        self._watch: asyncio.Task[None] | None = None
        # Called with (place, reason) when a goal this link started fails.
        self.on_failure: Callable[[str, str], None] | None = None

    # ------------------------------------------------------------ bus inputs
    def subscriptions(self) -> list[tuple[str, type, Callable[[Any], None]]]:
        """(topic, type, callback) for everything this link listens to."""
        return [
            (topics.BATTERY, BatteryState, self.on_battery),
            (topics.ESTOP, EStopState, self.on_estop),
            (topics.NAV_STATE, NavigateFeedback, self.on_nav_state),
            (topics.LOC_HEALTH, LocalizationHealth, self.on_health),
        ]

    def on_battery(self, msg: BatteryState) -> None:
        self.battery = msg

    def on_estop(self, msg: EStopState) -> None:
        self.estop = msg

    def on_nav_state(self, msg: NavigateFeedback) -> None:
        self.nav_state = msg

    def on_health(self, msg: LocalizationHealth) -> None:
        now = self.bus.clock.now()
        self.health, self._health_at = msg, now
        if not msg.lost:
            self._lost_since = None
        elif self._lost_since is None:
            self._lost_since = now

    def on_event(self, event: Event) -> None:
        if event.kind == "arrived" and not self.nav.touring:
            self.nav = NavStatus()

    # ------------------------------------------------------------ state
    def battery_fraction(self) -> float | None:
        """The charge 0..1, or None when unknown (no reading, or NaN)."""
        b = self.battery
        if b is None or not math.isfinite(b.percentage):
            return None
        return min(max(b.percentage, 0.0), 1.0)

    def lost(self) -> bool:
        """Localization has said "lost" for ``LOST_CONFIRM_S`` and is still talking, or the
        navigator itself reports being lost."""
        if self.nav_state is not None and self.nav_state.state is NavState.LOST:
            return True
        now = self.bus.clock.now()
        return (
            self._lost_since is not None
            and now - self._health_at <= HEALTH_STALE_S
            and now - self._lost_since >= LOST_CONFIRM_S
        )

    def estop_state(self) -> EStopState | None:
        """The e-stop as latched on the bus right now (no wait for a callback), else the
        last one handed to :meth:`on_estop`; None when nobody has published one."""
        latched = self.bus.latest(topics.ESTOP)
        return latched if isinstance(latched, EStopState) else self.estop

    def readiness(self) -> Readiness:
        e = self.estop_state()
        return Readiness(
            estop=bool(e and e.engaged),
            estop_by=e.by if e else "",
            battery=self.battery_fraction(),
            lost=self.lost(),
            battery_critical=self.battery_critical,
            battery_low=self.battery_low,
        )

    def motion(self) -> NavStatus:
        """What navigation is doing: the brain's own goal, else the navigator's state."""
        if self.nav.navigating:
            return self.nav
        fb = self.nav_state
        if fb is not None and fb.state is not NavState.IDLE:
            return NavStatus.from_navigator(fb)
        return self.nav

    def status(self) -> str:
        """Navigation and safety in one line, for the system prompt and the tools."""
        return f"{self.motion().describe()}; {self.readiness().describe()}"

    # ------------------------------------------------------------ places
    async def places(self) -> Places:
        """The building's places: from the navigator's service, else the waypoints file."""
        now = self.bus.clock.now()
        if self._places is not None and now - self._places_at < PLACES_TTL_S:
            return self._places
        fetched = await self._fetch_places()
        if fetched is not None:
            self._places, self._places_at = fetched, now
        elif self._places is None:
            self._places = self._load_fallback()
        return self._places

    async def _fetch_places(self) -> Places | None:
        if not self.bus.has_service(topics.PLACES):
            return None
        try:
            reply = await self.bus.call(topics.PLACES, Text(""), timeout=SERVICE_TIMEOUT_S)
        except ServiceError as exc:
            _log.warning("place list unavailable: %s", exc)
            return None
        if not isinstance(reply, PlaceList):
            return None
        return Places(
            [Place(p.name, p.pose, p.description, tuple(p.aliases)) for p in reply.places],
            topics.PLACES,
        )

    def _load_fallback(self) -> Places:
        if self.fallback_places is None:
            return Places([])
        try:
            return load_places(self.fallback_places)
        except ConfigError as exc:
            _log.warning("no places: %s", exc)
            return Places([])

    # ------------------------------------------------------------ navigation
    async def navigate(self, place: Place) -> Outcome:
        """Start driving to ``place`` and return once navigation took the goal (the
        arrival comes as an event); refused when the robot can not drive now."""
        refused = self.readiness().refuse_drive(place.name)
        if refused is not None:
            return Outcome(False, refused[1], refused=refused[0])
        if not self.bus.actions.has(topics.NAVIGATE_TO):
            return Outcome(False, NAV_DOWN_LINE, refused=Refusal.NAVIGATION)
        handle = await self.bus.actions.send_goal(topics.NAVIGATE_TO, NavigateGoal(place=place.name))
        turned_down = await self._turned_down(handle)
        if turned_down:
            return Outcome(False, turned_down, refused=Refusal.NAVIGATION)
        self._track(handle, place.name, touring=False)
        return Outcome(True, data={"place": place.name, "status": "navigating"})

    async def tour(self, names: list[str]) -> Outcome:
        refused = self.readiness().refuse_tour()
        if refused is not None:
            return Outcome(False, refused[1], refused=refused[0])
        if not self.bus.actions.has(topics.TOUR):
            return Outcome(False, TOUR_DOWN_LINE, refused=Refusal.NAVIGATION)
        handle = await self.bus.actions.send_goal(topics.TOUR, TourGoal(places=tuple(names)))
        turned_down = await self._turned_down(handle)
        if turned_down:
            return Outcome(False, turned_down, refused=Refusal.NAVIGATION)
        self._track(handle, names[0], touring=True)
        return Outcome(True, data={"places": names, "status": "touring"})

    async def _turned_down(self, handle: GoalHandle) -> str:
        """Navigation's reason when it ended the goal at once ('' when it is running): the
        visitor must not hear "follow me" for a goal that never started."""
        deadline = asyncio.get_running_loop().time() + ACCEPT_WAIT_S
        while not handle.done and handle.last_feedback is None:
            if asyncio.get_running_loop().time() >= deadline:
                return ""  # still working on it (waiting for a pose, planning): taken
            await asyncio.sleep(ACCEPT_POLL_S)
        if not handle.done:
            return ""
        result = await handle.result()
        value = result.value
        if result.ok and getattr(value, "succeeded", True):
            return ""  # already there
        return getattr(value, "reason", "") or result.message or "navigation did not take the goal"

    async def cancel(self) -> Outcome:
        stopped, was = False, self.nav.target
        if self.bus.has_service(topics.CANCEL_NAV):
            try:
                await self.bus.call(topics.CANCEL_NAV, Text(""), timeout=SERVICE_TIMEOUT_S)
                stopped = True
            except ServiceError as exc:
                _log.warning("cancel service failed: %s", exc)
        if self._goal is not None and not self._goal.done:
            with contextlib.suppress(GoalTimeout):  # asked to stop; it winds down by itself
                await self._goal.cancel()
            stopped = True
        self.nav = NavStatus()
        if not stopped:
            if self.bus.actions.has(topics.NAVIGATE_TO):
                return Outcome(True, data={"stopped": False, "note": "I was not going anywhere"})
            return Outcome(False, "navigation is not running right now")
        return Outcome(True, data={"stopped": True, "was_going_to": was})

    def _track(self, handle: GoalHandle, target: str, touring: bool) -> None:
        self._goal = handle
        self.nav = NavStatus(True, target, "planning", 0.0, touring)
        if self._watch is not None:
            self._watch.cancel()
        self._watch = asyncio.get_running_loop().create_task(self._follow(handle, target))

    async def _follow(self, handle: GoalHandle, target: str) -> None:
        async for fb in handle.feedback():
            if self._goal is not handle:
                return
            if isinstance(fb, NavigateFeedback):
                self.nav.state = fb.state.value
                self.nav.distance_remaining_m = fb.distance_remaining_m
                self.nav.target = fb.place or self.nav.target
            elif isinstance(fb, TourFeedback):
                self.nav.target, self.nav.state = fb.place, fb.state.value
        result = await handle.result()
        if self._goal is not handle:
            return
        self.nav = NavStatus()
        value = result.value
        failed = result.status is GoalStatus.ABORTED or (result.ok and not getattr(value, "succeeded", True))
        if failed and self.on_failure is not None:
            reason = getattr(value, "reason", "") or result.message or "navigation failed"
            self.on_failure(target, reason)

    async def close(self) -> None:
        if self._watch is not None:
            self._watch.cancel()
            await asyncio.gather(self._watch, return_exceptions=True)

    # ------------------------------------------------------------ where, kb
    async def where_am_i(self) -> Outcome:
        if not self.bus.has_service(topics.WHERE_AM_I):
            return Outcome(False, "localization is not running right now")
        try:
            reply = await self.bus.call(topics.WHERE_AM_I, Text(""), timeout=SERVICE_TIMEOUT_S)
        except ServiceError as exc:
            return Outcome(False, f"I could not ask localization: {exc}")
        if not isinstance(reply, WhereAmI):
            return Outcome(False, "localization gave an answer I do not understand")
        return Outcome(True, data=reply)

    async def kb_search(self, query: str, top_k: int) -> Outcome:
        if not self.bus.has_service(topics.KB_SEARCH):
            return Outcome(False, "the knowledge base is not running right now")
        try:
            reply = await self.bus.call(
                topics.KB_SEARCH, SearchRequest(query=query, top_k=top_k), timeout=KB_TIMEOUT_S
            )
        except ServiceError as exc:
            return Outcome(False, f"the knowledge base search failed: {exc}")
        if not isinstance(reply, SearchResponse):
            return Outcome(False, "the knowledge base gave an answer I do not understand")
        passages: tuple[Passage, ...] = reply.passages
        return Outcome(True, data=passages)
