"""The world node ("sim_world"): owns the simulated world and publishes what it senses.

At the very start of ``setup`` (before any ``await``) it puts the :class:`World` in
``ctx.resources[WORLD_RESOURCE]`` and its body in ``ctx.resources[SIM_BODY]``; the
simulated MCU ("mcu_sim") finds the body there and moves it by the firmware model's wheel
speeds. Its own physics hook (in ``ctx.resources[SIM_STEP_HOOKS]``) steps the people
every 10 ms and publishes, on the simulated clock: the lidar scan (10 Hz, ``/scan``),
ground truth (50 Hz, ``/sim/ground_truth``), people and the speaker's bearing (10 Hz), collisions as they
happen, and camera frames (``camera_hz`` frames per *wall* second: an operator watches
in real time, so a 50x run does not render 50x the frames; and only while something
subscribes to the camera topic: nobody watching, nothing rendered).

With no "mcu_sim" node in the launch, it drives the body itself from ``/cmd_vel``
(ideal tracking, the MCU's 0.55 s watchdog), so a world-only run still moves.
It also plays a scenario's timed events (``ctx.resources[SCENARIO_RESOURCE]``).
"""

from __future__ import annotations

import asyncio
import math
import time
from typing import Any

from sage_robot.core import topics
from sage_robot.core.errors import ConfigError, SageError
from sage_robot.core.msgs import Event, Odometry, Pose2D, Text, Twist
from sage_robot.core.msgs.voice import Doa
from sage_robot.core.node import LAUNCHER, SIM_STEP_HOOKS, Node
from sage_robot.core.resources import ResourceKey
from sage_robot.sim.mcu_pty import MCU_SIM_RESOURCE, SIM_BODY
from sage_robot.sim.scenario import Scenario, TimedEvent
from sage_robot.sim.setup import build_world
from sage_robot.sim.world import Collision, World

WORLD_RESOURCE = ResourceKey("sim_world", World, "set by the sim_world node")
SCENARIO_RESOURCE = ResourceKey("sim_scenario", Scenario)  # the Scenario being run (optional)
# Scenario results: goals, conversations, arrivals (lists of dicts), for `sage sim`'s summary
SUMMARY_RESOURCE: ResourceKey[dict[str, Any]] = ResourceKey("sim_summary", dict)
MCU_NODE = "mcu_sim"  # the simulated MCU's node name
TRUTH_HZ = 50.0
PEOPLE_HZ = 10.0
WATCHDOG_S = 0.55  # as the MCU firmware: a command older than this stops the body
CMD_RESEND_S = 0.05  # a scenario's standing /cmd_vel is re-sent at 20 Hz
EVENT_SOURCE = "sim"
EXCUSE_ME_EVENT = "blocked_by_people"  # the navigator's "excuse me, may I pass?"


class WorldNode(Node):
    name = "sim_world"

    async def setup(self) -> None:
        if not self.clock.is_simulated:
            raise ConfigError("the simulated world needs the simulated clock (`sage sim`)")
        self.scenario: Scenario | None = self.ctx.resources.get(SCENARIO_RESOURCE)
        world = self.ctx.resources.get(WORLD_RESOURCE)
        if not isinstance(world, World):  # a restart keeps the world (and the robot's pose)
            world = build_world(self.settings, self.scenario)
            self.ctx.resources[WORLD_RESOURCE] = world
        self.ctx.resources[SIM_BODY] = world.body
        self.world: World = world
        self.world.on_collision[:] = [self._on_collision]
        self.summary: dict[str, Any] = self.ctx.resources.setdefault(SUMMARY_RESOURCE, {"goals": []})
        self._failed = asyncio.Event()
        self._error: BaseException | None = None
        self._hooks = self.ctx.resources.setdefault(SIM_STEP_HOOKS, [])
        self._hooks.insert(0, self._physics)
        self.spawn(self._watch(), name="sim_world.watch")
        launcher = self.ctx.resources.get(LAUNCHER)
        self.direct_drive = MCU_NODE not in (launcher.node_names() if launcher is not None else [])
        self._cmd, self._cmd_t = Twist(), -math.inf
        if self.direct_drive:
            self.subscribe(topics.CMD_VEL, Twist, self._on_cmd)
        self.subscribe(topics.EVENTS, Event, self._on_event, maxsize=1000)
        self._events = list(self.scenario.events) if self.scenario else []
        self._battery_pending = self.scenario.battery if self.scenario and not self.direct_drive else None
        self._standing: Twist | None = None
        self._next = {"scan": 0.0, "truth": 0.0, "people": 0.0, "resend": 0.0}
        self._camera_wall = 0.0
        self.scans = self.frames = 0
        sim = self.settings.sim
        self._camera_period_wall = 1.0 / sim.camera_hz if sim.camera_hz > 0 else math.inf
        self.log.info(
            "simulated world ready",
            pose=[round(v, 2) for v in world.pose],
            people=len(world.crowd.people),
            low_obstacles=len(world.low_obstacles),
            direct_drive=self.direct_drive,
        )

    async def teardown(self) -> None:
        hooks = getattr(self, "_hooks", [])
        if self._physics in hooks:
            hooks.remove(self._physics)

    def stats(self) -> dict[str, Any]:
        w = self.world
        return {
            "scans": self.scans,
            "frames": self.frames,
            "collisions": w.collisions,
            "distance_m": round(w.distance_m, 2),
            "people": len(w.crowd.people),
        }

    # ---------------------------------------------------------------- inputs
    def _on_cmd(self, msg: Twist) -> None:
        self._cmd, self._cmd_t = msg, self.clock.now()

    def _on_collision(self, c: Collision) -> None:
        self.bus.publish(
            topics.SIM_COLLISIONS,
            Event(
                self.clock.now(),
                EVENT_SOURCE,
                "collision",
                f"hit {c.name} at {c.speed_mps:.2f} m/s",
                {
                    "kind": c.kind,
                    "name": c.name,
                    "x": f"{c.x:.3f}",
                    "y": f"{c.y:.3f}",
                    "speed_mps": f"{c.speed_mps:.3f}",
                },
            ),
        )

    # ---------------------------------------------------------------- the step
    def _physics(self, dt: float) -> None:
        """The hook: a failure here fails this node (restarted by the launcher, world kept)
        instead of stopping the simulator's clock."""
        try:
            self._step(dt)
        except Exception as exc:
            if self._physics in self._hooks:
                self._hooks.remove(self._physics)
            self._error = exc
            self._failed.set()

    async def _watch(self) -> None:
        await self._failed.wait()
        raise RuntimeError(f"physics step failed: {self._error!r}") from self._error

    def _step(self, dt: float) -> None:
        now = self.clock.now()
        if self._battery_pending is not None:
            self._apply_battery()
        self._play_events(now)
        if self.direct_drive:
            self._drive_direct(dt, now)
        self.world.step(dt)
        self._publish_due(now + dt)

    def _drive_direct(self, dt: float, now: float) -> None:
        cmd = self._cmd if now - self._cmd_t <= WATCHDOG_S else Twist()
        robot = self.settings.robot
        v = max(-robot.max_linear_mps, min(robot.max_linear_mps, cmd.linear_x))
        w = max(-robot.max_angular_radps, min(robot.max_angular_radps, cmd.angular_z))
        self.world.move(dt, v, w)

    def _due(self, key: str, t: float, hz: float) -> bool:
        if t + 1e-9 < self._next[key]:
            return False
        self._next[key] = max(self._next[key] + 1.0 / hz, t)
        return True

    def _publish_due(self, t: float) -> None:
        w = self.world
        if self._due("truth", t, TRUTH_HZ):
            self.bus.publish(
                topics.SIM_TRUTH, Odometry(t, Pose2D(*w.pose), Twist(w.v, w.w), "map", "base_link")
            )
        if self._due("scan", t, w.lidar.spec.rate_hz):
            self.bus.publish(topics.SCAN, w.scan(t))
            self.scans += 1
        if self._due("people", t, PEOPLE_HZ):
            self.bus.publish(topics.SIM_PEOPLE, w.people_msg(t))
            speaker = w.speaker(t)
            self.bus.publish(topics.SIM_SPEAKER, speaker)
            if speaker.present:
                self.bus.publish(topics.SIM_SPEAKER_BEARING, Doa(t, speaker.angle_deg, "sim"))
        wall = time.monotonic()  # camera frames are paced in wall time (see the module doc)
        if wall - self._camera_wall >= self._camera_period_wall:
            self._camera_wall = wall
            if self._camera_watched():  # rendering costs ~45 % of the loop: only for a viewer
                self.bus.publish(topics.CAMERA, w.camera_msg(t))
                self.frames += 1

    def _camera_watched(self) -> bool:
        return self.bus.has_readers(topics.CAMERA)  # a page here or in the web's process

    def _apply_battery(self) -> None:
        """The scenario's initial charge, set once on the firmware model's battery (its
        ``charge``, 0..1) as soon as the simulated MCU node is up."""
        mcu = self.ctx.resources.get(MCU_SIM_RESOURCE)
        battery = getattr(getattr(mcu, "firmware", None), "battery", None)  # not every dialect has one
        if battery is not None and hasattr(battery, "charge"):
            battery.charge = self._battery_pending
            self.log.info("scenario battery set", charge=self._battery_pending)
            self._battery_pending = None

    # ---------------------------------------------------------------- scenario
    def _play_events(self, now: float) -> None:
        while self._events and self._events[0].at <= now + 1e-9:
            self._play(self._events.pop(0), now)
        if self._standing is not None and now + 1e-9 >= self._next["resend"]:
            self._next["resend"] = now + CMD_RESEND_S
            self.bus.publish(topics.CMD_VEL, self._standing)

    def _play(self, ev: TimedEvent, now: float) -> None:
        self.log.info("scenario event", at=ev.at, action=ev.action, value=str(ev.value))
        if ev.action == "cmd_vel":
            v, w = ev.value
            self._standing = Twist(v, w)
            self._next["resend"] = now
        elif ev.action == "heard":  # a visitor's words, already transcribed
            self.spawn(self._visitor_heard(ev.value), name="sim_world.heard")
        elif ev.action == "say":  # the voice node speaks it into the simulated microphone
            self.bus.publish(topics.SIM_VISITOR_SAY, Text(ev.value))
        elif ev.action == "goal":
            self.spawn(self._send_goal(ev.value), name="sim_world.goal")
        elif ev.action == "stop":
            launcher = self.ctx.resources.get(LAUNCHER)
            if launcher is not None:
                launcher.request_stop()
        self.bus.publish(
            topics.EVENTS, Event(now, EVENT_SOURCE, "scenario_event", f"{ev.action}: {ev.value}")
        )

    async def _visitor_heard(self, words: str) -> None:
        """A visitor's transcribed words, handled as the voice pipeline handles a turn after
        STT: ``/sage/heard`` as a notification, the words as a ``converse`` goal to the
        brain, each streamed sentence on ``/sage/say`` (the voice node speaks it when it
        runs). The voice area's simulated microphone takes audio only (no text API in
        ``ctx.resources``; spoken words are the ``say`` action), so the brain is asked
        directly. What came of it goes into the summary's ``conversations``."""
        record: dict[str, Any] = {"heard": words, "sent_s": round(self.clock.now(), 2)}
        self.summary.setdefault("conversations", []).append(record)
        self.bus.publish(topics.HEARD, Text(words))
        if not self.bus.actions.has(topics.CONVERSE):
            record["status"] = "no brain"
            self.log.warning("scenario words not answered: nothing serves converse", heard=words)
            return
        replies: list[str] = record.setdefault("replies", [])
        try:
            handle = await self.bus.actions.send_goal(topics.CONVERSE, Text(words))
            async for fb in handle.feedback():
                if isinstance(fb, Text) and fb.data:
                    self._say(fb.data, replies)
            result = await handle.result()
        except SageError as exc:  # the brain went away in between: a result, not a crash
            record.update(status="error", message=str(exc))
            return
        if not replies and result.ok and isinstance(result.value, Text) and result.value.data:
            self._say(result.value.data, replies)
        record.update(status=result.status.value, done_s=round(self.clock.now(), 2))
        if result.message:
            record["message"] = result.message

    def _say(self, sentence: str, replies: list[str]) -> None:
        replies.append(sentence)
        self.bus.publish(topics.SAY, Text(sentence))

    def _on_event(self, ev: Event) -> None:
        """Arrivals (the navigator's events) go into the summary, whoever sent the goal; the
        robot's "excuse me" (``blocked_by_people``) is heard by the people in front of it."""
        if ev.kind == EXCUSE_ME_EVENT:
            moved = self.world.ask_aside()
            self.log.info("excuse me heard", stepping_aside=moved)
        if ev.kind == "arrived":
            place = ev.data.get("place", "")
            self.summary.setdefault("arrivals", []).append(
                {"place": place, "at_s": round(ev.stamp, 2), "message": ev.message}
            )

    async def _send_goal(self, place: str) -> None:
        from sage_robot.core.msgs.nav import NavigateGoal

        record: dict[str, Any] = {"goal": place, "sent_s": round(self.clock.now(), 2)}
        self.summary["goals"].append(record)
        if not self.bus.actions.has(topics.NAVIGATE_TO):
            record["status"] = "no navigation node"
            self.log.warning("scenario goal skipped: nothing serves navigate_to", goal=place)
            return
        try:
            handle = await self.bus.actions.send_goal(topics.NAVIGATE_TO, NavigateGoal(place=place))
            result = await handle.result()
        except SageError as exc:  # the server went away in between: a result, not a crash
            record.update(status="error", message=str(exc))
            return
        record.update(status=result.status.value, message=result.message, done_s=round(self.clock.now(), 2))
