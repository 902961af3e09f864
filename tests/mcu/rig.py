"""Test rig: a simulated MCU behind a real pty, with the real serial bridge, on the SimClock."""

from __future__ import annotations

import asyncio
import time
from dataclasses import dataclass, field
from typing import Any

from sage_robot.app.runtime import SIM_STEP_HOOKS, SIM_STEP_S
from sage_robot.core import topics
from sage_robot.core.bus import Bus
from sage_robot.core.clock import SimClock
from sage_robot.core.config import load_profile
from sage_robot.core.msgs import BatteryState, DiagnosticStatus, Imu, Odometry, Twist
from sage_robot.core.node import NodeContext
from sage_robot.hardware.mcu.bridge import SerialBridgeNode
from sage_robot.sim.mcu_pty import McuSimNode

SETTLE_TIMEOUT_S = 3.0  # real seconds to let the RX thread catch up (bounded)
REPEAT_S = 0.1  # a held command is re-published this often, as teleop and the navigator do


@dataclass
class Rig:
    ctx: NodeContext
    clock: SimClock
    sim: McuSimNode
    bridge: SerialBridgeNode
    odom: list[Odometry] = field(default_factory=list)
    battery: list[BatteryState] = field(default_factory=list)
    imu: list[Imu] = field(default_factory=list)
    status: list[DiagnosticStatus] = field(default_factory=list)
    lost_odom: int = 0  # ODOM frames sent before the bridge listened (flushed on open)
    held: Twist | None = None  # the command the rig keeps publishing (None: silent)
    held_t: float = 0.0

    @property
    def firmware(self) -> Any:
        return self.sim.firmware

    def command(self, v: float, w: float = 0.0) -> None:
        """Publish ``(v, w)`` and keep re-publishing it every REPEAT_S, as a live publisher does."""
        self.held, self.held_t = Twist(v, w), self.clock.now()
        self.ctx.bus.publish(topics.CMD_VEL, self.held)

    def go_silent(self) -> None:
        """The publisher stops publishing (crashed, frozen): the last command stands on the bus."""
        self.held = None

    async def run(self, seconds: float, real_sleep_s: float = 0.0) -> None:
        """Step the simulation ``seconds`` (physics hooks, then the clock)."""
        for _ in range(round(seconds / SIM_STEP_S)):
            if self.held is not None and self.clock.now() - self.held_t >= REPEAT_S - 1e-9:
                self.held_t = self.clock.now()
                self.ctx.bus.publish(topics.CMD_VEL, self.held)
            for hook in list(self.ctx.resources[SIM_STEP_HOOKS]):
                hook(SIM_STEP_S)
            await self.clock.step(SIM_STEP_S)
            if real_sleep_s:
                await asyncio.sleep(real_sleep_s)

    async def settle(self) -> None:
        """Wait (real time, bounded) until the bridge decoded every ODOM frame sent."""
        deadline = time.monotonic() + SETTLE_TIMEOUT_S
        while time.monotonic() < deadline:
            got = self.bridge.decoder.stats.frames["ODOM"]
            if got >= self.firmware.frames_sent["ODOM"] - self.lost_odom:
                break
            await asyncio.sleep(0.002)
        for _ in range(5):  # let call_soon_threadsafe deliveries and callbacks run
            await asyncio.sleep(0.002)

    async def until(self, predicate: Any, max_seconds: float, real_sleep_s: float = 0.002) -> float:
        """Step until ``predicate()``; return the simulated time it took (fails if never)."""
        t0 = self.clock.now()
        while not predicate():
            assert self.clock.now() - t0 < max_seconds, f"not reached within {max_seconds} s"
            await self.run(SIM_STEP_S, real_sleep_s)
        return self.clock.now() - t0


async def make_rig(overrides: dict[str, Any] | None = None) -> Rig:
    clock = SimClock()
    ctx = NodeContext(Bus(clock), clock, load_profile(None, overrides))
    ctx.resources[SIM_STEP_HOOKS] = []
    sim = McuSimNode(ctx)
    await sim.setup()
    bridge = SerialBridgeNode(ctx)
    rig = Rig(ctx, clock, sim, bridge)
    ctx.bus.subscribe(topics.ODOM, Odometry, rig.odom.append, maxsize=100000)
    ctx.bus.subscribe(topics.BATTERY, BatteryState, rig.battery.append, maxsize=100000)
    ctx.bus.subscribe(topics.IMU, Imu, rig.imu.append, maxsize=100000)
    ctx.bus.subscribe(topics.MCU_STATUS, DiagnosticStatus, rig.status.append, maxsize=1000)
    await bridge.setup()
    await rig.until(lambda: bridge.connected, 2.0)
    await asyncio.sleep(0.05)
    rig.lost_odom = rig.firmware.frames_sent["ODOM"] - bridge.decoder.stats.frames["ODOM"]
    return rig


async def close_rig(rig: Rig) -> None:
    for node in (rig.bridge, rig.sim):
        await node._close()
        await node.teardown()
