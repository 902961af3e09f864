"""The ``tour`` node: plans visitors' tours and runs them stop by stop.

- Service :data:`topics.TOUR_PLAN` (:class:`TourRequest` → :class:`TourPlan`): places for the
  visitor's interests and time (:mod:`sage_robot.brain.tours`), in route order, with path
  lengths on the latched ``/map`` (:mod:`sage_robot.brain.tour_routes`, built in a worker
  thread) from the robot's pose (``/amcl_pose``); straight lines until the map is there.
- Service :data:`topics.TOUR_CONTROL` (:class:`TourCommand` → :class:`TourState`): ``start``
  (places in order), ``pause``, ``resume``, ``skip``, ``stop``. A command that does not fit
  the state is answered ``ok=False`` with the reason; nothing raises for it.
- Topic :data:`topics.TOUR_STATE` (latched): the tour as the face and teleop pages show it.

A tour is consecutive ``navigate_to`` goals. At each stop the navigator's ``arrived`` event
makes the brain welcome the visitor; the node dwells ``DWELL_S`` and says where it goes next.
A goal someone else ends (the e-stop, the operator's or the face's Stop, a new goal) pauses
the tour; a stop it can not reach is skipped, with an apology. Every wait is bounded.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import math
from typing import Any

from sage_robot.brain.phrases import place_phrase, upper_first
from sage_robot.brain.tour_routes import RouteTable
from sage_robot.brain.tours import (
    CRUISE_FRACTION,
    DWELL_S,
    START,
    Candidate,
    Distance,
    candidates,
    interests_of,
    kb_keywords,
    named_places,
    plan_tour,
    straight_line,
)
from sage_robot.core import topics
from sage_robot.core.actions import GoalHandle, GoalStatus, GoalTimeout
from sage_robot.core.errors import ConfigError
from sage_robot.core.msgs import OccupancyGrid, PoseWithCovariance, Text
from sage_robot.core.msgs.nav import NavigateGoal
from sage_robot.core.msgs.tour import TOUR_COMMANDS, TourCommand, TourPhase, TourPlan, TourRequest, TourState
from sage_robot.core.node import Node
from sage_robot.core.paths import package_data, waypoints_yaml
from sage_robot.core.places import Place, Places, load_places

LEG_LIMIT_S = 600.0  # longest one leg may drive before it counts as failed (s)
PAUSE_LIMIT_S = 900.0  # a tour paused this long ends (s)
CANCEL_LIMIT_S = 3.0  # wall time a cancelled leg has to wind down
ROUTES_LATENCY_S = 3.0  # the route table may take this long (the robot goes on meanwhile; s)
FROM_ROBOT_LATENCY_S = 0.1  # one path search from the robot, for a plan (s)
RUNNING = (TourPhase.DRIVING, TourPhase.AT_STOP)
SPEAKS_FOR_ITSELF = "brain"  # a command from the brain: its own reply tells the visitor
OUTSIDE_STOP = "navigation was stopped (the emergency stop, an operator or a new goal)"


class TourNode(Node):
    name = "tour"

    async def setup(self) -> None:
        self.places = self._load_places()
        self.kb = kb_keywords(package_data("kb", "places"))
        self.speed_mps = CRUISE_FRACTION * self.settings.robot.max_linear_mps
        self.dwell_s = DWELL_S
        self.routes: RouteTable | None = None
        self.pose: tuple[float, float] | None = None
        self.state = TourState()
        self._epoch = 0  # bumped by every command: a leg that sees it change leaves the rest to it
        self._wake = asyncio.Event()
        self._goal: GoalHandle | None = None
        self._task: asyncio.Task[Any] | None = None
        self.tours = 0
        self.bus.declare(topics.TOUR_STATE, TourState, latched=True)
        self.bus.publish(topics.TOUR_STATE, self.state)
        self.subscribe(topics.MAP, OccupancyGrid, self._on_map, maxsize=1)
        self.subscribe(topics.AMCL_POSE, PoseWithCovariance, self._on_pose, maxsize=1)
        self.bus.serve(topics.TOUR_PLAN, self._plan)
        self.bus.serve(topics.TOUR_CONTROL, self._control)

    async def teardown(self) -> None:
        self.bus.unserve(topics.TOUR_PLAN)
        self.bus.unserve(topics.TOUR_CONTROL)
        if self._goal is not None:
            self._goal.request_cancel()
        if self._task is not None:
            self._task.cancel()

    def stats(self) -> dict[str, Any]:
        st = getattr(self, "state", TourState())
        routes = getattr(self, "routes", None) is not None
        return {"tours": getattr(self, "tours", 0), "phase": st.phase.value, "routes": routes}

    def _load_places(self) -> Places:
        try:
            return load_places(waypoints_yaml(self.settings))
        except ConfigError as exc:
            self.log.warning("no places for tours", error=str(exc))
            return Places([])

    # ------------------------------------------------------------ inputs
    def _on_pose(self, msg: PoseWithCovariance) -> None:
        self.pose = (msg.pose.x, msg.pose.y)

    async def _on_map(self, grid: OccupancyGrid) -> None:
        points = {p.name: (p.pose.x, p.pose.y) for p in self.places}
        radius = self.settings.robot.radius_m
        self.routes = await self.clock.offload(RouteTable, grid, points, radius, latency_s=ROUTES_LATENCY_S)
        self.log.info("tour routes ready", places=len(points))

    # ------------------------------------------------------------ planning
    async def distances(self) -> tuple[Distance, str]:
        """Path lengths on the map from the robot (straight lines until the map is there)."""
        table, pose = self.routes, self.pose
        if table is None:
            return straight_line(self.places, pose), "straight-line"
        first = None
        if pose is not None:
            first = await self.clock.offload(table.from_point, *pose, latency_s=FROM_ROBOT_LATENCY_S)

        def distance(a: str, b: str) -> float:
            if a == START:
                return 0.0 if first is None else first.get(b, math.inf)
            return table.between(a, b)

        return distance, "map"

    async def _plan(self, req: TourRequest) -> TourPlan:
        named, unknown = named_places(list(req.places), self.places)
        if unknown:
            return TourPlan(False, reason=f"I know no place called {', '.join(unknown)}")
        chosen = [Candidate(p, math.inf, "") for p in named]
        interests = interests_of(req.interests)
        if interests or not named:
            chosen += [c for c in candidates(self.places, interests, self.kb) if c.place not in named]
        distance, how = await self.distances()
        reachable = [c for c in chosen if math.isfinite(distance(START, c.place.name))]
        if chosen and not reachable:
            return TourPlan(False, reason="none of those places can be reached from here", distances=how)
        titles = {p.name: title(p) for p in self.places}
        budget = req.budget_s if req.budget_s > 0 else None
        return plan_tour(
            reachable, distance, self.speed_mps, budget, self.dwell_s, titles=titles, distances=how
        )

    # ------------------------------------------------------------ commands
    async def _control(self, cmd: TourCommand) -> TourState:
        if cmd.command not in TOUR_COMMANDS:
            return self._refuse(f"unknown tour command {cmd.command!r}; commands: {', '.join(TOUR_COMMANDS)}")
        if cmd.command == "start":
            return await self._start(cmd)
        phase = self.state.phase
        if cmd.command == "resume" and phase is not TourPhase.PAUSED:
            return self._refuse("the tour is not paused" if phase in RUNNING else "no tour is running")
        if cmd.command in ("pause", "skip", "stop") and phase not in (*RUNNING, TourPhase.PAUSED):
            return self._refuse("no tour is running")
        if cmd.command == "pause" and phase is TourPhase.PAUSED:
            return self._refuse("the tour is already paused")
        await getattr(self, f"_{cmd.command}")(cmd.by != SPEAKS_FOR_ITSELF)
        return self.state

    def _refuse(self, reason: str) -> TourState:
        return dataclasses.replace(self.state, ok=False, reason=reason)

    async def _start(self, cmd: TourCommand) -> TourState:
        stops, unknown = named_places(list(cmd.places), self.places)
        if unknown or not stops:
            why = f"I know no place called {', '.join(unknown)}" if unknown else "a tour needs places"
            return self._refuse(why)
        if not self.bus.actions.has(topics.NAVIGATE_TO):
            return self._refuse("navigation is not running right now")
        await self._end_leg()
        if self._task is not None:
            self._task.cancel()
        names = tuple(p.name for p in stops)
        titles = tuple(title(p) for p in stops)
        self._bump()
        self._publish(TourState(TourPhase.DRIVING, names, titles, 0, budget_s=cmd.budget_s,
                                estimate_s=cmd.estimate_s, started_at=self.clock.now()))  # fmt: skip
        self.tours += 1
        self._task = self.spawn(self._tour(), "tour.run")
        return self.state

    async def _pause(self, announce: bool) -> None:
        index = self.state.index + (1 if self.state.phase is TourPhase.AT_STOP else 0)  # that stop is done
        self._bump()
        self._set(phase=TourPhase.PAUSED, index=index, reason="paused")
        await self._end_leg()
        if announce:
            self._say("I will wait here. Say resume when you want to go on.")

    async def _resume(self, announce: bool) -> None:
        self._bump()
        self._set(phase=TourPhase.DRIVING, reason="")

    async def _skip(self, announce: bool) -> None:
        st = self.state
        passed = st.phase is TourPhase.AT_STOP or st.index >= len(st.stops)  # nothing left to skip there
        skipped = st.skipped if passed else (*st.skipped, st.stops[st.index])
        self._bump()
        self._set(phase=TourPhase.DRIVING, index=st.index + 1, skipped=skipped, reason="")
        await self._end_leg()

    async def _stop(self, announce: bool) -> None:
        self._bump()
        self._set(phase=TourPhase.STOPPED, reason="stopped on request")
        await self._end_leg()
        if announce:
            self._say("All right, the tour ends here. Thank you for coming along!")

    def _bump(self) -> None:
        self._epoch += 1
        self._wake.set()

    async def _end_leg(self) -> None:
        goal, self._goal = self._goal, None
        if goal is not None and not goal.done:
            with contextlib.suppress(GoalTimeout):
                await goal.cancel(timeout=CANCEL_LIMIT_S)

    # ------------------------------------------------------------ the tour
    async def _tour(self) -> None:
        while self.state.phase not in (TourPhase.STOPPED, TourPhase.DONE):
            if self.state.index >= len(self.state.stops):
                self._set(phase=TourPhase.DONE, reason="")
                self._say("That was the last stop of our tour. Thank you for visiting!")
                return
            if self.state.phase is TourPhase.PAUSED:
                await self._wait_paused()
            else:
                await self._leg()

    async def _wait_paused(self) -> None:
        epoch = self._epoch
        self._wake.clear()
        try:
            await self.clock.wait_for(self._wake.wait(), PAUSE_LIMIT_S)
        except asyncio.TimeoutError:
            if self._epoch == epoch:
                self._set(phase=TourPhase.STOPPED, reason="paused for too long")

    async def _leg(self) -> None:
        epoch, st = self._epoch, self.state
        name = st.stops[st.index]
        self._set(phase=TourPhase.DRIVING)
        if st.index > 0 or st.visited or st.skipped:
            self._say(f"Next, {place_phrase(name)}. Follow me!")
        handle = self._goal = await self.bus.actions.send_goal(topics.NAVIGATE_TO, NavigateGoal(place=name))
        try:
            result = await self.clock.wait_for(handle.result(), LEG_LIMIT_S)
        except asyncio.TimeoutError:
            handle.request_cancel()
            result = None
        if self._epoch != epoch:
            return  # a command took over (pause, skip, stop, a new tour)
        self._goal = None
        if result is not None and result.status in (GoalStatus.CANCELED, GoalStatus.PREEMPTED):
            self._bump()
            self._set(phase=TourPhase.PAUSED, reason=OUTSIDE_STOP)
            return
        if result is None or not result.ok or not getattr(result.value, "succeeded", True):
            why = "it took too long"
            if result is not None:
                why = getattr(result.value, "reason", "") or result.message or "navigation failed"
            self._say(f"Sorry, I can not get to {place_phrase(name)}: {why.rstrip('.')}. Let us go on.")
            self._set(index=st.index + 1, skipped=(*self.state.skipped, name))
            return
        self._set(phase=TourPhase.AT_STOP, visited=(*self.state.visited, name))
        self._wake.clear()
        with contextlib.suppress(asyncio.TimeoutError):
            await self.clock.wait_for(self._wake.wait(), self.dwell_s)
        if self._epoch == epoch:
            self._set(index=st.index + 1)

    # ------------------------------------------------------------ output
    def _set(self, **changes: Any) -> None:
        self._publish(dataclasses.replace(self.state, ok=True, **changes))

    def _publish(self, state: TourState) -> None:
        self.state = state
        self.bus.publish(topics.TOUR_STATE, state)

    def _say(self, sentence: str) -> None:
        self.bus.publish(topics.SAY, Text(upper_first(sentence)))


def title(place: Place) -> str:
    """What pages call a place: its title, else its spoken name without "the"."""
    return place.title or place_phrase(place).removeprefix("the ")
