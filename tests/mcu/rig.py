"""Test rig: a simulated MCU behind a real pty, with the real serial bridge, on the SimClock."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from sage_robot.app.runtime import SIM_STEP_S
from sage_robot.core import topics
from sage_robot.core.bus import Bus
from sage_robot.core.clock import SimClock
from sage_robot.core.config import load_profile
from sage_robot.core.msgs import BatteryState, DiagnosticStatus, Imu, Odometry, Twist
from sage_robot.core.node import SIM_STEP_HOOKS, NodeContext
from sage_robot.hardware.mcu.bridge import SerialBridgeNode
from sage_robot.sim.mcu_pty import McuSimNode

from ..support.waits import describe, drain, until

SETTLE_TIMEOUT_S = 10.0  # wall s bound on the bridge reading what is waiting (a few loop turns)
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

    async def run(self, seconds: float) -> None:
        """Step the simulation ``seconds`` (physics hooks, then the clock)."""
        for _ in range(round(seconds / SIM_STEP_S)):
            if self.held is not None and self.clock.now() - self.held_t >= REPEAT_S - 1e-9:
                self.held_t = self.clock.now()
                self.ctx.bus.publish(topics.CMD_VEL, self.held)
            hooks = self.ctx.resources[SIM_STEP_HOOKS]
            for hook in list(hooks):
                hook(SIM_STEP_S)
            await self.clock.step(SIM_STEP_S)

    def _port_read(self) -> bool:
        port = self.bridge._port  # read on simulated-clock timers: nothing left after a step
        return port is None or port.in_waiting == 0

    async def settle(self) -> None:
        """Wait (wall clock, bounded) until the bridge has read every byte waiting on its port,
        then let the bus deliver what it published."""
        await until(self._port_read, "the bridge to read what waits on its port", SETTLE_TIMEOUT_S)
        await drain(20)

    async def until(self, predicate: Any, max_seconds: float) -> float:
        """Step until ``predicate()``; return the simulated time it took (fails if never)."""
        t0 = self.clock.now()
        while not predicate():
            assert self.clock.now() - t0 < max_seconds, (
                f"not reached within {max_seconds} simulated s: {describe(predicate)}")
            await self.run(SIM_STEP_S)
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
    return rig


async def close_rig(rig: Rig) -> None:
    for node in (rig.bridge, rig.sim):
        await node._close()
        await node.teardown()
