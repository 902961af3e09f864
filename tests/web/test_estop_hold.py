"""The e-stop's hold cancels a goal this process cannot see as an action (sent from another
process to the navigator in a third): the navigator's latched state says it drives (#24)."""

from __future__ import annotations

import asyncio
import math
from types import SimpleNamespace
from typing import Any, cast

from sage_robot.core import topics
from sage_robot.core.bus import Bus
from sage_robot.core.clock import SimClock
from sage_robot.core.config import Settings
from sage_robot.core.msgs.nav import NavigateFeedback, NavState
from sage_robot.web.teleop import Teleop


async def test_the_estop_hold_asks_the_navigator_to_cancel_while_its_state_says_it_drives() -> None:
    clock = SimClock()
    bus = Bus(clock)
    cancels: list[object] = []

    async def cancel(request: object) -> None:
        cancels.append(request)

    bus.serve(topics.CANCEL_NAV, cancel)
    spawned: list[asyncio.Task[Any]] = []

    def spawn(coro: Any, name: str) -> None:
        spawned.append(asyncio.get_running_loop().create_task(coro, name=name))

    node = SimpleNamespace(bus=bus, clock=clock, settings=Settings.model_validate({}), spawn=spawn)
    teleop = Teleop(cast(Any, node), SimpleNamespace(estop=True))
    bus.declare(topics.NAV_STATE)
    bus.publish(topics.NAV_STATE, NavigateFeedback(NavState.DRIVING, "lab"))  # no goal visible here
    teleop._hold_estop()
    await asyncio.gather(*spawned)
    assert len(cancels) == 1
    assert teleop.counts["estop_cancels"] == 1
    teleop._hold_estop()  # the next look, 20 ms later: not asked again yet
    assert len(spawned) == 1
    bus.publish(topics.NAV_STATE, NavigateFeedback(NavState.IDLE))  # cancelled: nothing runs
    teleop._estop_cancel_at = -math.inf
    teleop._hold_estop()
    assert len(spawned) == 1
