"""Goals, cancels, preemptions, e-stops and node restarts in any order never wedge the robot.

A hypothesis state machine fires random overlapping calls at the real navigator (its
``navigate_to`` and ``tour`` actions and its cancel service), the real offline brain (the
``converse`` action, which itself starts navigation goals), the web's real teleop e-stop,
and restarts of the navigator and brain nodes — all on one real bus, with the simulated
robot driving (tests/nav/nav_sim.py). After every step it checks:

- every call answered within its bound (sending a goal never waits for another goal; a
  cancel ends the goal within the action layer's bound);
- whenever no navigation goal is active, the last command on ``/cmd_vel`` is a stop;
- while the e-stop is engaged no navigation goal survives and the wire says stop;
- every goal ever sent ends with a result once it was cancelled or its server restarted.
"""

from __future__ import annotations

import asyncio
import tempfile
from pathlib import Path
from typing import Any

from hypothesis import HealthCheck, settings
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, invariant, precondition, rule

from sage_robot.brain.node import BrainNode
from sage_robot.core import topics
from sage_robot.core.actions import CANCEL_WAIT_S, GoalHandle
from sage_robot.core.msgs import Text, Twist
from sage_robot.core.msgs.nav import NavigateGoal, TourGoal
from sage_robot.core.node import Node, NodeContext
from sage_robot.nav.navigator import NavigatorNode
from sage_robot.web.teleop import Teleop

from ..support.grids import draw
from ..support.waits import until
from .nav_sim import running, settings_for, write_building

CALL_BOUND_S = 0.5  # sending a goal, engaging the e-stop: wall seconds at most
CANCEL_BOUND_S = CANCEL_WAIT_S + 1.0  # a cancel, including the handler's clean-up
BURST_BOUND_S = 20.0  # ten offline answers in turn, wall s
SETTLE_BOUND_S = 10.0  # wall s an invariant may take to hold after a step (teleop's checks are wall-clock)

ROOMS = """
######################
#......#######.......#
#....................#
#....................#
#......#######.......#
######################
"""
A, B = (1.5, 1.5, 0.0), (9.5, 1.5, 0.0)
PLACES = ("ROOM_A", "ROOM_B", "NOWHERE")
QUESTIONS = ("take me to room b", "take me to room a", "stop", "where am I", "hello", "give me a tour")


class _Hub:
    """The web hub's two members that teleop uses (page fan-out is not under test here)."""

    def __init__(self) -> None:
        self.estop = False
        self.sent: list[tuple[str, Any]] = []

    def set(self, channel: str, value: Any) -> None:
        self.sent.append((channel, value))


class Robot(RuleBasedStateMachine):
    def __init__(self) -> None:
        super().__init__()
        self.loop = asyncio.new_event_loop()
        self.handles: list[GoalHandle] = []
        self.cmds: list[Twist] = []
        self.loop.run_until_complete(self._start())

    # ------------------------------------------------------------ plumbing
    async def _start(self) -> None:
        self.tmp = tempfile.TemporaryDirectory(prefix="sage-actions-")
        grid = draw(ROOMS, 0.05, scale=10)
        path = write_building(Path(self.tmp.name), grid, {"ROOM_A": A, "ROOM_B": B})
        cfg = settings_for(path, "ROOM_A")
        self._running = running(cfg, grid, A, speed=None)
        self.bus, self.clock, self.sim = await self._running.__aenter__()
        self.cmd_sub = self.bus.subscribe(topics.CMD_VEL, Twist, self.cmds.append, maxsize=100000)
        self.ctx = NodeContext(self.bus, self.clock, cfg)
        self.navigator = next(n for n in self.sim.nodes if isinstance(n, NavigatorNode))
        self.brain = BrainNode(self.ctx)
        await self.brain.setup()
        self.web = Node(self.ctx)
        self.hub = _Hub()
        self.teleop = Teleop(self.web, self.hub)
        self.teleop.start()

    def run(self, coro: Any, bound: float, what: str) -> Any:
        async def bounded() -> Any:
            try:
                return await asyncio.wait_for(coro, bound)
            except asyncio.TimeoutError:
                raise AssertionError(f"{what} did not answer within {bound} s") from None

        return self.loop.run_until_complete(bounded())

    def eventually(self, cond: Any, what: str) -> None:
        """Run the loop until ``cond()`` holds (bounded): the nodes react to a step asynchronously."""
        self.loop.run_until_complete(until(cond, what, SETTLE_BOUND_S))

    def _nav_active(self) -> list[GoalHandle]:
        return [h for a in (topics.NAVIGATE_TO, topics.TOUR) if (h := self.bus.actions.active(a)) is not None]

    # ------------------------------------------------------------ rules
    @rule(place=st.sampled_from(PLACES))
    def navigate(self, place: str) -> None:
        if self.bus.actions.has(topics.NAVIGATE_TO):
            self.handles.append(self.run(self.bus.actions.send_goal(
                topics.NAVIGATE_TO, NavigateGoal(place=place)), CALL_BOUND_S, "send navigate_to"))

    @rule(places=st.lists(st.sampled_from(PLACES[:2]), min_size=1, max_size=3))
    def tour(self, places: list[str]) -> None:
        if self.bus.actions.has(topics.TOUR):
            goal = TourGoal(places=tuple(places), dwell_s=0.5)
            self.handles.append(self.run(self.bus.actions.send_goal(topics.TOUR, goal),
                                         CALL_BOUND_S, "send tour"))

    @rule(text=st.sampled_from(QUESTIONS))
    def ask(self, text: str) -> None:
        if self.bus.actions.has(topics.CONVERSE):
            self.handles.append(self.run(self.bus.actions.send_goal(topics.CONVERSE, Text(text)),
                                         CALL_BOUND_S, "send converse"))

    @rule(first=st.sampled_from(PLACES), second=st.sampled_from(PLACES), cancel=st.booleans())
    def double_click(self, first: str, second: str, cancel: bool) -> None:
        """Two goals in the same instant (a double click), maybe cancelled before either ran."""
        if not self.bus.actions.has(topics.NAVIGATE_TO):
            return

        async def clicks() -> list[GoalHandle]:
            send = self.bus.actions.send_goal
            got = list(await asyncio.gather(send(topics.NAVIGATE_TO, NavigateGoal(place=first)),
                                            send(topics.NAVIGATE_TO, NavigateGoal(place=second))))
            if cancel:  # before the loop ran either handler
                for result in await asyncio.gather(*(h.cancel() for h in got)):
                    assert result.status.done
            return got

        self.handles += self.run(clicks(), CANCEL_BOUND_S, "a double click")

    @rule(k=st.integers(2, 10))
    def question_burst(self, k: int) -> None:
        """k visitors ask at once: every one gets an answer (in turn), none hangs."""
        if not self.bus.actions.has(topics.CONVERSE):
            return

        async def burst() -> None:
            handles = await asyncio.gather(*(self.bus.actions.send_goal(topics.CONVERSE, Text("hello"))
                                             for _ in range(k)))
            self.handles.extend(handles)
            results = await asyncio.gather(*(h.result(BURST_BOUND_S) for h in handles))
            assert all(r.status.done for r in results)

        self.run(burst(), BURST_BOUND_S + 1.0, f"{k} simultaneous questions")

    @precondition(lambda self: self.handles)
    @rule(data=st.data())
    def cancel(self, data: st.DataObject) -> None:
        handle = data.draw(st.sampled_from(self.handles))
        result = self.run(handle.cancel(), CANCEL_BOUND_S, f"cancel of goal {handle.goal_id}")
        assert result.status.done
        assert handle.done

    @rule()
    def cancel_service(self) -> None:
        if self.bus.has_service(topics.CANCEL_NAV):
            self.run(self.bus.call(topics.CANCEL_NAV, None, timeout=CANCEL_BOUND_S),
                     CANCEL_BOUND_S + 0.5, "the cancel service")

    @rule(engaged=st.booleans())
    def estop(self, engaged: bool) -> None:
        was = self.teleop.estop
        self.run(self.teleop.set_estop(engaged, "test"), CALL_BOUND_S, "set_estop")
        if engaged and not was:  # the wire first: the stop is out before the call returns
            assert self.cmds
            assert self.cmds[-1].is_zero

    @rule(which=st.sampled_from(("navigator", "brain")))
    def restart(self, which: str) -> None:
        node = self.navigator if which == "navigator" else self.brain

        async def again() -> Node:
            await node._close()
            await node.teardown()
            fresh = NavigatorNode(self.ctx) if which == "navigator" else BrainNode(self.ctx)
            await fresh.setup()
            return fresh

        fresh = self.run(again(), CANCEL_BOUND_S + 2.0, f"restart of {which}")
        if which == "navigator":
            self.sim.nodes[self.sim.nodes.index(self.navigator)] = fresh  # closed at the end
            self.navigator = fresh
        else:
            self.brain = fresh

    @rule(seconds=st.sampled_from((0.1, 0.5, 2.0)))
    def wait(self, seconds: float) -> None:
        self.run(self.clock.sleep(seconds), 30.0, f"{seconds} simulated s")

    # ------------------------------------------------------------ invariants
    @invariant()
    def stopped_without_a_goal(self) -> None:
        self.eventually(lambda: self._nav_active() or not self.cmds or self.cmds[-1].is_zero,
                        "a stop command once no goal is active")

    @invariant()
    def estop_holds(self) -> None:
        if self.teleop.estop:
            self.eventually(lambda: not [h for h in self._nav_active() if not h.cancel_requested],
                            "every goal to be asked to stop under e-stop")
            self.eventually(lambda: not self.cmds or self.cmds[-1].is_zero, "a stop command under e-stop")

    def teardown(self) -> None:
        try:
            for handle in self.handles:
                self.run(handle.cancel(), CANCEL_BOUND_S, f"final cancel of goal {handle.goal_id}")
            assert all(h.done for h in self.handles)

            async def stop() -> None:
                for node in (self.brain, self.web):
                    await node._close()
                    await node.teardown()
                await self._running.__aexit__(None, None, None)
                self.cmd_sub.close()

            self.run(stop(), 30.0, "shutdown")
        finally:
            leftover = asyncio.all_tasks(self.loop)  # subscriptions' pumps closed above
            for task in leftover:
                task.cancel()
            self.loop.run_until_complete(asyncio.gather(*leftover, return_exceptions=True))
            self.loop.close()
            self.tmp.cleanup()


Robot.TestCase.settings = settings(
    max_examples=8, stateful_step_count=12, deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much],
)
TestGoalsCancelsEstopsRestarts = Robot.TestCase
