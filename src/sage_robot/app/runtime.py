"""Build a process: clock, bus, context and launcher for a profile, then run it."""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable
from typing import Any

from sage_robot.app.launcher import Launcher, NodeSpec
from sage_robot.app.profiles import PROFILES
from sage_robot.app.registry import node_class
from sage_robot.core.bus import Bus, LocalTransport, Transport
from sage_robot.core.clock import Clock, SimClock, WallClock
from sage_robot.core.config import Settings
from sage_robot.core.errors import ConfigError
from sage_robot.core.node import SIM_STEP_HOOKS, NodeContext

SIM_STEP_S = 0.01  # physics step of the simulator (s): the firmware model's 100 Hz loop


def specs_for(mode: str, extra: list[str] | None = None) -> list[NodeSpec]:
    if mode not in PROFILES:
        raise ConfigError(f"unknown mode {mode!r}; modes: {', '.join(sorted(PROFILES))}")
    entries = list(PROFILES[mode]) + [(n, False) for n in (extra or [])]
    return [NodeSpec(name, node_class(name), critical) for name, critical in entries]


def make_transport(settings: Settings) -> Transport:
    """The bus's transport as the profile's ``bus.transport`` names it."""
    if settings.bus.transport == "local":
        return LocalTransport()
    try:
        from sage_robot.core.transport.zenoh_bus import ZenohTransport
    except ImportError as exc:
        raise ConfigError(
            f"bus.transport: zenoh needs the zenoh extra (pip install 'sage-robot[zenoh]'): {exc}"
        ) from None
    from sage_robot.web.auth import operator_password

    return ZenohTransport(settings.bus, lambda: operator_password(settings))


def make_context(settings: Settings, simulated: bool) -> NodeContext:
    clock: Clock = SimClock() if simulated else WallClock()
    ctx = NodeContext(Bus(clock, make_transport(settings)), clock, settings)
    ctx.resources[SIM_STEP_HOOKS] = []
    return ctx


async def run_launcher(
    ctx: NodeContext,
    specs: list[NodeSpec],
    until: float | None = None,
    after_start: Callable[[Launcher], Awaitable[Any]] | None = None,
) -> Launcher:
    """Run nodes until a signal, or (simulated) until the clock reaches ``until``; the bus's
    transport is closed at the end."""
    try:
        return await _run(ctx, specs, until, after_start)
    finally:
        ctx.bus.transport.close()


async def _run(
    ctx: NodeContext,
    specs: list[NodeSpec],
    until: float | None,
    after_start: Callable[[Launcher], Awaitable[Any]] | None,
) -> Launcher:
    launcher = Launcher(ctx, specs)
    launcher.install_signal_handlers()
    await launcher.start()
    if after_start is not None:
        await after_start(launcher)
    if isinstance(ctx.clock, SimClock):
        hooks = ctx.resources[SIM_STEP_HOOKS]

        def physics(dt: float) -> None:
            for hook in hooks:
                hook(dt)

        stepper = asyncio.get_running_loop().create_task(
            ctx.clock.run(SIM_STEP_S, ctx.settings.sim.speed, until, launcher._stop_event, physics)
        )
        stop_waiter = asyncio.get_running_loop().create_task(launcher._stop_event.wait())
        await asyncio.wait({stepper, stop_waiter}, return_when=asyncio.FIRST_COMPLETED)
        stepper.cancel()
        stop_waiter.cancel()
        if stepper.done() and not stepper.cancelled() and stepper.exception():
            raise stepper.exception()  # type: ignore[misc]
    else:
        await launcher._stop_event.wait()
    await launcher.stop()
    return launcher
