"""The real simulator nodes (world, simulated MCU over a pseudo-terminal, serial bridge) with
map_server, localization and navigator, on the SimClock as fast as the machine allows:
from the docking station, out of its alcove, to the café, without touching anything."""

from __future__ import annotations

import asyncio
import math

import pytest

from sage_robot.app.launcher import Launcher, NodeSpec
from sage_robot.app.registry import node_class
from sage_robot.app.runtime import make_context, run_launcher
from sage_robot.core import topics
from sage_robot.core.config import load_profile
from sage_robot.core.msgs import Event, Odometry
from sage_robot.core.msgs.nav import LocalizationHealth, NavigateFeedback, NavigateGoal, NavState
from sage_robot.sim.node import WORLD_RESOURCE

NODES = ["sim_world", "mcu_sim", "serial_bridge", "map_server", "localization", "navigator"]
SIM_LIMIT_S = 200.0  # simulated seconds before the run gives up (the drive takes ~100)
WALL_LIMIT_S = 200.0  # real seconds (about 35 on this shared 2-core machine)
CAFE = (31.1, 44.6)  # GUELLY_DELLY in the shipped waypoints
ARRIVED_TRUTH_M = 0.4  # goal tolerance 0.25 m on the estimate + localization error


@pytest.mark.slow
async def test_dock_to_cafe_on_the_real_simulator() -> None:
    settings = load_profile(None, {"sim": {"speed": None, "pedestrians": 0},
                                   "nav": {"initial_place": "DOCKING_STATION"}})
    ctx = make_context(settings, simulated=True)
    specs = [NodeSpec(n, node_class(n), False) for n in NODES]
    events: list[Event] = []
    states: list[NavState] = []
    lost: list[float] = []
    truth: list[tuple[float, float]] = []
    result = []

    async def after_start(launcher: Launcher) -> None:
        ctx.bus.subscribe(topics.EVENTS, Event, events.append, maxsize=100)
        ctx.bus.subscribe(topics.NAV_STATE, NavigateFeedback, lambda m: states.append(m.state), maxsize=100)
        ctx.bus.subscribe(topics.LOC_HEALTH, LocalizationHealth,
                          lambda h: lost.append(h.stamp) if h.lost else None, maxsize=100)
        ctx.bus.subscribe(topics.SIM_TRUTH, Odometry, lambda m: truth.append((m.pose.x, m.pose.y)),
                          maxsize=100)

        async def drive() -> None:
            await ctx.clock.sleep(2.0)  # the brain asks ~2 s after start at the earliest
            handle = await ctx.bus.actions.send_goal(topics.NAVIGATE_TO, NavigateGoal(place="GUELLY_DELLY"))
            result.append(await handle.result())
            launcher.request_stop()

        asyncio.get_running_loop().create_task(drive())

    launcher = await asyncio.wait_for(run_launcher(ctx, specs, until=SIM_LIMIT_S, after_start=after_start),
                                      WALL_LIMIT_S)  # fmt: skip
    assert result, (result, [(e.kind, e.message) for e in events])
    assert result[0].ok, (result, [(e.kind, e.message) for e in events])
    kinds = [e.kind for e in events if e.source == "navigator"]
    assert kinds == ["arrived"], kinds  # no lost, no blocked_by_people on the way
    assert not lost
    assert NavState.LOST not in states
    assert ctx.resources[WORLD_RESOURCE].collisions == 0
    x, y = truth[-1]
    assert math.hypot(x - CAFE[0], y - CAFE[1]) <= ARRIVED_TRUTH_M
    assert not any(h.restarts for h in launcher.health.values())
