"""The serial bridge on a clock that follows the simulator's (process groups): it reads the
simulated MCU's pty in its own loop, and at rest its watch turns when bytes come in."""

from __future__ import annotations

import itertools

from sage_robot.app.runtime import SIM_STEP_S
from sage_robot.core.bus import Bus
from sage_robot.core.clock import SimClock
from sage_robot.core.clock_follow import FollowerClock
from sage_robot.core.config import load_profile
from sage_robot.core.node import SIM_STEP_HOOKS, NodeContext
from sage_robot.hardware.mcu.bridge import (
    IDLE_CHECK_S,
    IDLE_TURN_ON_READ_S,
    PORT_READ_ELSEWHERE,
    PORT_RESOURCE,
    SerialBridgeNode,
)
from sage_robot.sim.mcu_pty import McuSimNode

from ..support.waits import drain, until

READ_TIMEOUT_S = 10.0  # wall s bound on the bridge's loop reading what waits on its port


async def test_at_rest_the_watch_turns_on_the_firmwares_bytes_and_on_its_timer_without_them():
    """While the firmware's bytes come (every 20 ms), the watch's turns ride on their reads
    (the process wakes for nothing else at rest); when they stop, its own timer still turns it
    every IDLE_CHECK_S (the link is watched whether or not bytes come)."""
    settings = load_profile(None)
    sim_clock, clock = SimClock(), FollowerClock()  # the follower moves only when told (no pace)
    sim_ctx = NodeContext(Bus(sim_clock), sim_clock, settings)
    sim_ctx.resources[SIM_STEP_HOOKS] = []
    sim_ctx.resources[PORT_READ_ELSEWHERE] = True  # the bridge reads in "another process"
    sim = McuSimNode(sim_ctx)
    await sim.setup()
    ctx = NodeContext(Bus(clock), clock, settings)
    ctx.resources[PORT_RESOURCE] = sim_ctx.resources[PORT_RESOURCE]
    bridge = SerialBridgeNode(ctx)
    turns: list[float] = []
    watch_turn = bridge._watch_turn

    def counted(now: float) -> None:
        turns.append(round(now, 6))
        watch_turn(now)

    bridge._watch_turn = counted  # type: ignore[method-assign]
    await bridge.setup()

    async def step(pump: bool) -> None:
        clock.follow(sim_clock.now() + SIM_STEP_S)  # the step's time, before its bytes are read
        if pump:
            hooks = sim_ctx.resources[SIM_STEP_HOOKS]
            for hook in list(hooks):
                hook(SIM_STEP_S)
        await sim_clock.step(SIM_STEP_S)
        await until(lambda: bridge.decoder.stats.bytes_in == sim.pty.bytes_written,
                    "the bridge read what the firmware wrote", READ_TIMEOUT_S)
        await drain(10)

    try:
        for _ in range(50):  # the link comes up, the firmware starts sending
            await step(pump=True)
        assert bridge.connected
        turns.clear()
        for _ in range(100):  # one simulated second at rest, bytes every 20 ms
            await step(pump=True)
        gaps = [round(b - a, 6) for a, b in itertools.pairwise(turns)]
        assert gaps, "the watch never turned"
        # every turn on a read (at least IDLE_TURN_ON_READ_S after the last), never the timer's
        assert all(IDLE_TURN_ON_READ_S - 1e-6 <= g < IDLE_CHECK_S for g in gaps), gaps
        turns.clear()
        for _ in range(30):  # the firmware goes quiet: the timer turns the watch
            await step(pump=False)
        gaps = [round(b - a, 6) for a, b in itertools.pairwise(turns)]
        assert gaps, "the watch stopped turning"
        assert all(abs(g - IDLE_CHECK_S) < 1e-6 for g in gaps), gaps
    finally:
        for node in (bridge, sim):
            await node._close()
            await node.teardown()
