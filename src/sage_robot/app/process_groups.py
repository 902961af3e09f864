"""Process groups under one supervisor: each group of nodes in its own process.

The profile's ``processes.groups`` splits a mode's nodes into groups (motion, nav, voice,
brain, web, sim, ...). :class:`GroupSupervisor` starts each as
``python -m sage_robot.app.group_main --group NAME ...``, and when one ends without being
asked (a crash, ``kill -9``, the out-of-memory killer) it records the exit, stops the robot
if the group held a critical node (a zero ``/cmd_vel`` and a ``safety_stop`` event, as the
launcher does for a node), and starts it again after a delay that doubles with each crash
(:data:`BACKOFF_INITIAL_S` … :data:`BACKOFF_MAX_S`). The other groups go on untouched.

Health: each group's launcher reports on ``/sage/group_health/<group>``; the supervisor
merges the reports into ``/sage/health`` (what the pages show) every
:data:`HEALTH_PERIOD_S` and at every change, with one ``process:<group>`` entry per group
(state, restarts, exit, pid). A group counts as running once its first report came in.

The groups talk through the supervisor's Zenoh router (:mod:`.zenoh_hub`). In the simulator
the ``sim`` group steps the clock; it writes the time on a shared page in the run folder
(:mod:`sage_robot.core.clock_board`) that the other groups and the supervisor read, and
publishes ``/clock`` for tools and for processes on other machines.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import signal
import sys
import time
from dataclasses import dataclass, field
from typing import Any, Protocol

from sage_robot.app.group_main import group_health_topic
from sage_robot.core import event_loop, topics
from sage_robot.core.clock_board import ClockBoard
from sage_robot.core.config import Settings
from sage_robot.core.config.processes import CLOCK_GROUP, group_of
from sage_robot.core.errors import ConfigError
from sage_robot.core.log import get_logger
from sage_robot.core.msgs import Event, HealthReport, NodeHealth, Twist
from sage_robot.core.msgs.clock import SimTime
from sage_robot.core.node import NodeState
from sage_robot.hardware.mcu.port import heartbeat_fd

BACKOFF_INITIAL_S = 0.5  # first restart delay after a crash (s, wall)
BACKOFF_MAX_S = 10.0  # the delay doubles up to this (s)
STABLE_AFTER_S = 30.0  # a group that ran this long starts again from the initial delay (s)
HEALTH_PERIOD_S = 1.0  # the merged /sage/health goes out at least this often (s)
STOP_GRACE_S = 5.0  # SIGTERM, then this long before SIGKILL (s)
PROCESS_PREFIX = "process:"  # health entries of the groups themselves
MCU_LINK = "mcu_port"  # in the run folder: the link to the simulated MCU's pty
CLOCK_BOARD = "clock.board"  # in the run folder: the simulator's time (group_main --clock-board)
BRIDGE_NODE = "serial_bridge"


class Hub(Protocol):
    """Where the supervisor reads and writes bus messages (:class:`.zenoh_hub.ZenohHub`)."""

    endpoint: str

    def subscribe(self, topic: str, callback: Any) -> None: ...
    def publish(self, topic: str, msg: Any) -> None: ...
    def close(self) -> None: ...


@dataclass
class GroupPlan:
    """One group: its nodes and how its process is started (the start time comes later)."""

    name: str
    nodes: list[str]
    critical: bool
    argv: list[str]
    clock: str = "wall"  # source | follow | wall (group_main --clock)
    board: str = ""  # the shared page of the simulator's time (group_main --clock-board)


@dataclass
class GroupProcess:
    plan: GroupPlan
    proc: asyncio.subprocess.Process | None = None
    state: NodeState = NodeState.CREATED
    restarts: int = 0
    last_error: str = ""
    started_at: float | None = None
    report: HealthReport | None = None
    pids: list[int] = field(default_factory=list)  # every pid it had, the current last
    spawned: list[float] = field(default_factory=list)  # when each was started (monotonic s)

    @property
    def pid(self) -> int:
        return self.pids[-1] if self.pids else 0


def plan_groups(
    settings: Settings,
    mode: str,
    nodes: list[tuple[str, bool]],
    endpoint: str,
    run_dir: str,
    profile: str | None = None,
    overrides: dict[str, Any] | None = None,
) -> list[GroupPlan]:
    """The groups that run ``nodes`` (name, critical) of ``mode``, the simulator's first."""
    groups = group_of(settings.processes.groups, [n for n, _ in nodes])
    critical = {n for n, c in nodes if c}
    simulated = mode.startswith("sim")
    if simulated and CLOCK_GROUP not in groups:
        raise ConfigError(
            f"processes: a simulated run needs the {CLOCK_GROUP!r} group (it steps the clock); "
            f"the groups here are {', '.join(groups)}"
        )
    order = sorted(groups, key=lambda g: g != CLOCK_GROUP)
    link = os.path.join(run_dir, MCU_LINK)
    board = os.path.join(run_dir, CLOCK_BOARD)
    plans = []
    for name in order:
        members = groups[name]
        argv = [sys.executable, "-m", "sage_robot.app.group_main", "--group", name, "--mode", mode,
                "--nodes", ",".join(members), "--connect", endpoint,
                "--overrides", json.dumps(overrides or {})]
        nice = settings.processes.nice.get(name, 0)
        if nice:
            argv += ["--nice", str(nice)]
        realtime = settings.processes.realtime.get(name, 0)
        if realtime:
            argv += ["--realtime", str(realtime)]
        if profile:
            argv += ["--profile", profile]
        clock = "wall"
        if simulated:
            clock = "source" if name == CLOCK_GROUP else "follow"
            if name == CLOCK_GROUP:
                argv += ["--export-port", link]
            if BRIDGE_NODE in members:
                argv += ["--mcu-port", link]
            argv += ["--clock-board", board]
        argv += ["--clock", clock]
        plans.append(GroupPlan(name, members, any(n in critical for n in members), argv, clock,
                               board if simulated else ""))
    return plans


def exit_reason(rc: int) -> str:
    return f"killed by signal {-rc}" if rc < 0 else f"exit status {rc}"


class GroupSupervisor:
    """Starts every group, restarts a crashed one with backoff, merges their health."""

    def __init__(self, plans: list[GroupPlan], hub: Hub) -> None:
        self.groups = {p.name: GroupProcess(p) for p in plans}
        self.hub = hub
        boards = {p.board for p in plans if p.board}
        if len(boards) > 1:
            raise ConfigError(f"process groups: one simulator's time, not {len(boards)} ({sorted(boards)})")
        # the simulator's time: a new page, before any group starts (they open it)
        self.board = ClockBoard.create(boards.pop()) if boards else None
        self.log = get_logger("process_groups")
        self._clock_seen: float | None = None  # the last /clock (without a board)
        self._stopping = False
        self._stop_event = asyncio.Event()
        self._tasks: list[asyncio.Task[None]] = []

    # ---------------------------------------------------------------- public
    async def run(self) -> None:
        """Start, wait for :meth:`request_stop` (or SIGINT/SIGTERM), stop every group."""
        await self.start()
        try:
            await self._stop_event.wait()
        finally:
            await self.stop()

    async def start(self) -> None:
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            with contextlib.suppress(NotImplementedError, RuntimeError):
                loop.add_signal_handler(sig, self.request_stop)
        if self.board is None:
            self.hub.subscribe(topics.CLOCK, self._on_clock)
        for name in self.groups:
            self.hub.subscribe(group_health_topic(name), lambda msg, g=name: self._on_report(g, msg))
        for g in self.groups.values():
            self._tasks.append(loop.create_task(self._supervise(g), name=f"group:{g.plan.name}"))
        self._tasks.append(loop.create_task(self._health_loop(), name="group_health"))

    def request_stop(self) -> None:
        self._stop_event.set()

    async def stop(self) -> None:
        """Every group asked to stop (the simulator last), killed after :data:`STOP_GRACE_S`."""
        self._stopping = True
        for task in self._tasks:
            task.cancel()
        for g in reversed(list(self.groups.values())):
            await self._end(g)
        self._publish_health()

    @property
    def sim_time(self) -> float | None:
        """The simulator's time as last written or published (None: none yet)."""
        if self.board is not None:
            reading = self.board.read()
            return None if reading is None else reading.t
        return self._clock_seen

    def health_msg(self) -> HealthReport:
        """Every node of every group (a down group's nodes in its state) and the groups."""
        nodes: list[NodeHealth] = []
        for g in self.groups.values():
            nodes += self._node_entries(g)
        nodes += [self._process_entry(g) for g in self.groups.values()]
        sim_time = self.sim_time
        stamp = sim_time if sim_time is not None else time.time()
        return HealthReport(stamp, tuple(nodes))

    # ---------------------------------------------------------------- supervision
    async def _supervise(self, g: GroupProcess) -> None:
        backoff = BACKOFF_INITIAL_S
        while not self._stopping:
            started = time.monotonic()
            rc = await self._run_once(g)
            if self._stopping:
                return
            g.last_error = f"process {exit_reason(rc)}"
            self.log.error("process group ended", group=g.plan.name, reason=g.last_error, pid=g.pid)
            self._on_down(g)
            if time.monotonic() - started > STABLE_AFTER_S:
                backoff = BACKOFF_INITIAL_S
            g.state, g.report = NodeState.BACKOFF, None
            g.restarts += 1
            self._publish_health()
            self.log.warning("restarting process group", group=g.plan.name, delay_s=round(backoff, 2))
            await asyncio.sleep(backoff)
            backoff = min(backoff * 2, BACKOFF_MAX_S)

    async def _run_once(self, g: GroupProcess) -> int:
        argv = list(g.plan.argv)
        sim_time = self.sim_time
        if g.plan.clock == "source" and sim_time is not None:
            argv += ["--start-time", repr(sim_time)]  # a restarted simulator goes on from there
        g.state, g.report = NodeState.STARTING, None
        beat = heartbeat_fd() if BRIDGE_NODE in g.plan.nodes else None  # `sage up`'s last word
        # Its stdin is a pipe nobody writes to: it reads end-of-file once this process is gone.
        g.proc = await asyncio.create_subprocess_exec(*argv, "--parent-pipe", stdin=asyncio.subprocess.PIPE,
                                                      pass_fds=(beat,) if beat is not None else ())
        g.pids.append(g.proc.pid)
        g.spawned.append(time.monotonic())
        self.log.info("process group started", group=g.plan.name, pid=g.proc.pid)
        self._publish_health()
        return await g.proc.wait()

    async def _end(self, g: GroupProcess) -> None:
        proc = g.proc
        if proc is not None and proc.returncode is None:
            with contextlib.suppress(ProcessLookupError):
                proc.terminate()
            try:
                await asyncio.wait_for(proc.wait(), STOP_GRACE_S)
            except asyncio.TimeoutError:
                self.log.warning("process group did not stop: killing it", group=g.plan.name)
                with contextlib.suppress(ProcessLookupError):
                    proc.kill()
                await proc.wait()
        g.state = NodeState.STOPPED

    def _on_down(self, g: GroupProcess) -> None:
        if not g.plan.critical:
            return
        self.log.error("critical process group down: stopping the robot", group=g.plan.name)
        sim_time = self.sim_time
        stamp = sim_time if sim_time is not None else time.time()
        try:
            self.hub.publish(topics.CMD_VEL, Twist())
            self.hub.publish(topics.EVENTS, Event(stamp, "supervisor", "safety_stop",
                                                  f"process {g.plan.name} is down: {g.last_error}"))
        except Exception:  # the stop must not end the supervision
            self.log.exception("cannot publish the stop")

    # ---------------------------------------------------------------- health
    def _on_clock(self, msg: SimTime) -> None:
        seen = self._clock_seen
        self._clock_seen = msg.clock if seen is None else max(seen, msg.clock)

    def _on_report(self, group: str, msg: HealthReport) -> None:
        g = self.groups[group]
        if g.state in (NodeState.BACKOFF, NodeState.STOPPED):
            return  # a report sent before it died
        g.report = msg
        if g.state is NodeState.STARTING:
            g.state, g.started_at = NodeState.RUNNING, msg.stamp
            self.log.info("process group running", group=group, pid=g.pid)
            self._publish_health()

    async def _health_loop(self) -> None:
        while True:
            self._publish_health()
            await asyncio.sleep(HEALTH_PERIOD_S)

    def _publish_health(self) -> None:
        try:
            self.hub.publish(topics.HEALTH, self.health_msg())
        except Exception:  # a report that cannot go out must not stop the supervision
            self.log.exception("cannot publish the health report")

    def _node_entries(self, g: GroupProcess) -> list[NodeHealth]:
        if g.state is NodeState.RUNNING and g.report is not None:
            return list(g.report.nodes)
        why = g.last_error or f"process {g.state.value}"
        return [NodeHealth(n, g.state.value, g.restarts, why, None, g.plan.critical) for n in g.plan.nodes]

    @staticmethod
    def _process_entry(g: GroupProcess) -> NodeHealth:
        stats = {"pid": g.pid, "nodes": ",".join(g.plan.nodes), "clock": g.plan.clock}
        return NodeHealth(f"{PROCESS_PREFIX}{g.plan.name}", g.state.value, g.restarts, g.last_error,
                          g.started_at, g.plan.critical, stats)


def hub_endpoints(settings: Settings) -> tuple[str, str]:
    """Where the supervisor's router listens (the profile's first ``bus.zenoh.listen``, so
    tools find the robot where they always do) and where the groups connect to it."""
    from sage_robot.core.transport.keys import tool_endpoints

    z = settings.bus.zenoh
    if z.mode != "peer" or not z.listen:
        raise ConfigError("processes: bus.zenoh must be in 'peer' mode with a listen endpoint "
                          "(the supervisor's router listens there)")
    return z.listen[0], tool_endpoints(z)[0]


def run_processes(
    settings: Settings,
    mode: str,
    nodes: list[tuple[str, bool]],
    profile: str | None = None,
    overrides: dict[str, Any] | None = None,
) -> GroupSupervisor:
    """Run ``nodes`` of ``mode`` as process groups until SIGINT/SIGTERM; the supervisor."""
    import tempfile

    from sage_robot.app.zenoh_hub import ZenohHub

    listen, connect = hub_endpoints(settings)
    with tempfile.TemporaryDirectory(prefix="sage-groups-") as run_dir:
        plans = plan_groups(settings, mode, nodes, connect, run_dir, profile, overrides)

        async def main() -> GroupSupervisor:
            z = settings.bus.zenoh
            hub = ZenohHub(listen, settings.bus.robot_id, z.runtime, z.tx_queue)
            supervisor = GroupSupervisor(plans, hub)
            try:
                await supervisor.run()
            finally:
                hub.close()
            return supervisor

        return event_loop.run(main(), fast=True)
