"""A two-stop tour with the real simulator, MCU link, map server, localization, navigator,
brain and tour node, on the simulated clock: the tour is paused on its first leg (the robot
stands), resumed, welcomed at the first stop, the dwell skipped, and it ends at the second."""

from __future__ import annotations

import asyncio

import pytest

from sage_robot.app.launcher import Launcher, NodeSpec
from sage_robot.app.registry import node_class
from sage_robot.app.runtime import make_context, run_launcher
from sage_robot.core import topics
from sage_robot.core.config import load_profile
from sage_robot.core.msgs import Event, Odometry, Text
from sage_robot.core.msgs.tour import TourCommand, TourPhase, TourState

NODES = ["sim_world", "mcu_sim", "serial_bridge", "map_server", "localization", "navigator", "brain", "tour"]
SIM_LIMIT_S = 240.0  # simulated seconds before the run gives up
WALL_LIMIT_S = 240.0  # real seconds (a loaded shared 2-core machine)
START = "CLEAN_ROOM"  # 10 m along the corridor from the 3D printing lab
STOPS = ("3D_PRINTING_LAB", "MANUFACTURING_LAB")
PAUSED_S = 5.0  # simulated seconds the tour stays paused
STANDING_MPS = 0.02  # ground-truth speed below which the robot stands


@pytest.mark.slow
async def test_two_stop_tour_on_the_simulated_robot() -> None:
    settings = load_profile(None, {"sim": {"speed": None, "pedestrians": 0}, "nav": {"initial_place": START}})
    ctx = make_context(settings, simulated=True)
    specs = [NodeSpec(n, node_class(n), False) for n in NODES]
    said: list[str] = []
    arrived: list[str] = []
    states: list[TourState] = []
    speed: list[float] = []
    log: list[str] = []
    paused_speed: list[float] = []  # top ground-truth speed while the tour was paused (m/s)

    async def control(command: str, *places: str) -> TourState:
        reply = await ctx.bus.call(topics.TOUR_CONTROL, TourCommand(command, places))
        assert isinstance(reply, TourState)
        assert reply.ok, reply.reason
        return reply

    async def until(cond: object, what: str) -> None:
        while not cond():  # type: ignore[operator]
            await ctx.clock.sleep(0.25)
        log.append(f"{ctx.clock.now():.1f} {what}")

    def on_event(e: Event) -> None:
        if e.kind == "arrived":
            arrived.append(e.data.get("place", ""))

    def driving() -> bool:
        return bool(states and states[-1].phase is TourPhase.DRIVING and speed and speed[-1] > 0.1)

    async def after_start(launcher: Launcher) -> None:
        ctx.bus.subscribe(topics.SAY, Text, lambda m: said.append(m.data), maxsize=100)
        ctx.bus.subscribe(topics.EVENTS, Event, on_event, maxsize=100)
        ctx.bus.subscribe(topics.TOUR_STATE, TourState, states.append, maxsize=100)
        ctx.bus.subscribe(topics.SIM_TRUTH, Odometry, lambda o: speed.append(abs(o.twist.linear_x)), 999)

        async def visitor() -> None:
            try:
                await ctx.clock.sleep(2.0)  # localization settles on the initial pose
                await control("start", *STOPS)
                await until(driving, "driving")
                await control("pause")
                await ctx.clock.sleep(PAUSED_S)
                speed.clear()
                await ctx.clock.sleep(1.0)
                paused_speed.append(max(speed, default=0.0))
                await control("resume")
                await until(lambda: states[-1].phase is TourPhase.AT_STOP, "at the first stop")
                await control("skip")
                await until(lambda: states[-1].phase in (TourPhase.DONE, TourPhase.STOPPED), "done")
            finally:
                launcher.request_stop()

        asyncio.get_running_loop().create_task(visitor())

    launcher = await asyncio.wait_for(run_launcher(ctx, specs, until=SIM_LIMIT_S, after_start=after_start),
                                      WALL_LIMIT_S)  # fmt: skip
    final = states[-1]
    assert final.phase is TourPhase.DONE, (final, log, said)
    assert final.visited == STOPS
    assert arrived == list(STOPS), log
    assert paused_speed[0] < STANDING_MPS, log
    assert any(s.startswith("Here we are at the 3D Printing Lab") for s in said), said
    assert any(s.startswith("Next, the Manufacturing Lab") for s in said), said
    assert any("last stop of our tour" in s for s in said), said
    assert ctx.clock.now() < SIM_LIMIT_S
    assert not any(h.restarts for h in launcher.health.values())
