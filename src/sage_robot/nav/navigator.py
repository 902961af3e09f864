"""The ``navigator`` node: the ``navigate_to`` and ``tour`` actions, ``/plan``, cancel.

Inputs: ``/odom`` + the map→odom correction (the pose), ``/scan`` (costmaps),
``/localization/health``, and Event ``places_changed`` (re-reads the waypoints file).
The global costmap (static + keepout + obstacles with ray-trace
clearing + inflation) is refreshed from the latest scan each time it plans; the rolling
local costmap (``nav.local_costmap_m`` square, live scan only) is rebuilt on every scan and
feeds the controller's proximity slowdown and forward collision check. How one goal is
driven, and recovered, is :mod:`sage_robot.nav.drive`.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy import ndimage

from sage_robot.core import topics
from sage_robot.core.actions import ActionAborted, GoalContext, GoalTimeout
from sage_robot.core.geometry import compose
from sage_robot.core.msgs import Event, LaserScan, OccupancyGrid, Odometry, Pose2D, PoseStamped, Text, Twist
from sage_robot.core.msgs import Path as PathMsg
from sage_robot.core.msgs.nav import (
    LocalizationHealth,
    NavigateFeedback,
    NavigateGoal,
    NavigateResult,
    NavState,
    TourFeedback,
    TourGoal,
    TourResult,
)
from sage_robot.core.node import Node
from sage_robot.core.places import Place
from sage_robot.nav.collision_guard import guarded, leg_like, scan_points
from sage_robot.nav.costmap import Costmap
from sage_robot.nav.costmap_msg import costmap_grid
from sage_robot.nav.drive import GoalRun, Target
from sage_robot.nav.mapdata import load_for, places_after

Pose = tuple[float, float, float]

GLOBAL_OBSTACLE_MEMORY_M = 12.0  # scan obstacles further than this from the robot are forgotten
STATE_PERIOD_S = 1.0  # NAV_STATE is repeated this often while a goal or tour runs (s)
COSTMAP_PERIOD_S = 1.0  # the local costmap is published this often for the operator's map (s)
UNKNOWN_HELD_CELLS = 2  # a leg-like return this close (cells) to the map's unknown is the map's
IDLE = NavigateFeedback(NavState.IDLE)


class NavigatorNode(Node):
    name = "navigator"

    async def setup(self) -> None:
        s = self.settings
        self.data = load_for(s)
        self.global_cm = self.data.costmap(s.robot.radius_m, s.nav.inflation_radius_m,
                                           s.nav.cost_scaling_factor)
        self.local_cm: Costmap | None = None
        self._odom: Pose | None = None
        self._correction: Pose | None = None
        self.scan: LaserScan | None = None
        self._scan_base: np.ndarray | None = None  # the latest scan's returns in the robot's frame
        self._scan_legs: np.ndarray | None = None  # ... which of them look like a person's legs
        self._held_cache: tuple[Costmap, np.ndarray] | None = None  # (costmap, what its map holds)
        self.guard_stops = 0  # commands the collision guard stopped (nav/collision_guard.py)
        self.health: LocalizationHealth | None = None
        self.commands = 0
        self.goals = 0
        self.subscribe(topics.ODOM, Odometry, self._on_odom, maxsize=50)
        self.subscribe(topics.MAP_ODOM, PoseStamped, self._on_correction)
        self.subscribe(topics.SCAN, LaserScan, self._on_scan, maxsize=1)
        self.subscribe(topics.LOC_HEALTH, LocalizationHealth, self._on_health)
        self.subscribe(topics.EVENTS, Event, self._on_event, maxsize=50)
        self.state = IDLE
        self._run: GoalRun | None = None
        self.bus.declare(topics.NAV_STATE, NavigateFeedback, latched=True)
        self.bus.publish(topics.NAV_STATE, self.state)
        self.every(STATE_PERIOD_S, self._repeat_state, "navigator.state")
        self.bus.declare(topics.COSTMAP, OccupancyGrid, latched=True)
        self.every(COSTMAP_PERIOD_S, self._publish_costmap, "navigator.costmap")
        self.bus.actions.serve(topics.NAVIGATE_TO, self._navigate)
        self.bus.actions.serve(topics.TOUR, self._tour)
        self.bus.serve(topics.CANCEL_NAV, self._cancel)
        self.bus.serve(topics.CLEAR_COSTMAPS, self._clear)

    async def teardown(self) -> None:
        for action in (topics.NAVIGATE_TO, topics.TOUR):
            self.bus.actions.unserve(action)
        for service in (topics.CANCEL_NAV, topics.CLEAR_COSTMAPS):
            self.bus.unserve(service)
        self.stop()

    # ------------------------------------------------------------ inputs
    def _on_odom(self, msg: Odometry) -> None:
        self._odom = msg.pose.as_tuple()

    def _on_correction(self, msg: PoseStamped) -> None:
        self._correction = msg.pose.as_tuple()

    def _on_health(self, msg: LocalizationHealth) -> None:
        self.health = msg

    def _on_event(self, event: Event) -> None:
        self.data = places_after(event, self.data, self.log)

    def _on_scan(self, msg: LaserScan) -> None:
        self.scan = msg
        lidar = self.settings.robot.lidar
        mount = (lidar.x_m, lidar.y_m, lidar.yaw_rad)
        self._scan_base = scan_points(msg.angles, msg.ranges, msg.range_max, mount)
        pose = self.pose()
        self._scan_legs = self._legs(self._scan_base, pose)
        if pose is None:
            return
        local = self.global_cm.window(pose[0], pose[1], self.settings.nav.local_costmap_m)
        local.update_scan(self.sensor_pose(pose), msg.angles, msg.ranges, msg.range_max)
        self.local_cm = local

    def _legs(self, base: np.ndarray, pose: Pose | None) -> np.ndarray | None:
        """Which returns look like a person's legs (the guard keeps the body off the body
        around them): leg-shaped, and not on the map's walls (a table's or a chair's legs,
        willow-full's furniture, are mapped; a person is not). Unlocalized: none."""
        if pose is None:
            return None
        legs = leg_like(base)
        if legs.any():
            c, s = math.cos(pose[2]), math.sin(pose[2])
            xs = pose[0] + c * base[legs, 0] - s * base[legs, 1]
            ys = pose[1] + s * base[legs, 0] + c * base[legs, 1]
            r, col = self.global_cm.geom.to_cell(xs, ys)
            ok = self.global_cm.geom.inside(r, col)
            mapped = np.ones(len(xs), dtype=bool)
            mapped[ok] = self._held()[r[ok], col[ok]]
            legs[np.flatnonzero(legs)[mapped]] = False
        return legs

    def _held(self) -> np.ndarray:
        """Cells on or beside anything the map holds: its walls (the costmap's wall zone) and
        its unknown cells, specks included (noise to the planner, but solid in a simulated
        world built from the map, and often furniture in a real one)."""
        if self._held_cache is not None and self._held_cache[0] is self.global_cm:
            return self._held_cache[1]
        g = self.data.grid
        raw = np.asarray(g.data).reshape(g.height, g.width)
        held: np.ndarray = self.global_cm.wall_zone.copy()
        if raw.shape == held.shape:
            held |= ndimage.binary_dilation(raw < 0, iterations=UNKNOWN_HELD_CELLS)
        self._held_cache = (self.global_cm, held)
        return held

    # ------------------------------------------------------------ helpers for GoalRun
    def pose(self) -> Pose | None:
        """The robot's pose in the map: correction ∘ odometry; None until localized."""
        if self._odom is None or self._correction is None:
            return None
        return compose(self._correction, self._odom)

    def sensor_pose(self, pose: Pose) -> Pose:
        lidar = self.settings.robot.lidar
        return compose(pose, (lidar.x_m, lidar.y_m, lidar.yaw_rad))

    def lost(self) -> bool:
        return bool(self.health is not None and self.health.lost)

    def command(self, v: float, w: float) -> float:
        """Publish (v, w) on /cmd_vel after the collision guard; returns the v sent."""
        if v < 0.0 and not self.settings.robot.allow_reverse:
            raise AssertionError("the navigator never reverses here")  # broken code, not bad input
        self.commands += 1
        if self._scan_base is not None:  # the live scan's last word: never onto something seen
            safe = guarded(v, w, self._scan_base, self.settings.robot.radius_m, legs=self._scan_legs)
            if safe != v:
                self.guard_stops += 1
                v = safe
        self.bus.publish(topics.CMD_VEL, Twist(float(v), float(w)))
        return v

    def stop(self) -> None:
        self.bus.publish(topics.CMD_VEL, Twist())

    def event(self, kind: str, message: str, **data: str) -> None:
        self.bus.publish(topics.EVENTS, Event(self.clock.now(), self.name, kind, message, dict(data)))

    def set_state(self, fb: NavigateFeedback) -> None:
        """Publish the navigator's state on NAV_STATE when it changes (state or place); the
        timer repeats the latest at 1 Hz (with fresh distance and ETA) while a goal runs."""
        changed = (fb.state, fb.place) != (self.state.state, self.state.place)
        self.state = fb
        if changed:
            self.bus.publish(topics.NAV_STATE, fb)

    def _busy(self) -> bool:
        return any(self.bus.actions.active(a) is not None for a in (topics.NAVIGATE_TO, topics.TOUR))

    def _repeat_state(self) -> None:
        if self.state.state is not NavState.IDLE or self._busy():
            self.bus.publish(topics.NAV_STATE, self.state)

    def _publish_costmap(self) -> None:
        if self.local_cm is not None:  # drawn on the teleop map (web: /ws/live "costmap")
            self.bus.publish(topics.COSTMAP, costmap_grid(self.local_cm, self.clock.now()))

    def publish_plan(self, points: np.ndarray) -> None:
        poses = tuple(Pose2D(float(x), float(y), 0.0) for x, y in points[::4])
        self.bus.publish(topics.PLAN, PathMsg(self.clock.now(), "map", poses))

    def refresh_global(self, pose: Pose | None, scan: LaserScan | None) -> None:
        """Mark ``scan``, taken at ``pose``, into the global costmap (runs in the planning
        thread: its inputs are taken on the event loop before, never read from here)."""
        if pose is not None and scan is not None:
            self.global_cm.update_scan(self.sensor_pose(pose), scan.angles, scan.ranges, scan.range_max,
                                       forget_beyond_m=GLOBAL_OBSTACLE_MEMORY_M)

    def clear_costmaps(self) -> None:
        self.global_cm.clear_obstacles()
        if self.local_cm is not None:
            self.local_cm.clear_obstacles()

    # ------------------------------------------------------------ services
    async def _cancel(self, _request: Any) -> Text:
        self.stop()  # the wire first; the goals wind down after
        stopped = []
        for action in (topics.TOUR, topics.NAVIGATE_TO):
            if await self._end_goal(action):
                stopped.append(action)
        self.stop()
        return Text("canceled " + ", ".join(stopped) if stopped else "nothing to cancel")

    async def _clear(self, _request: Any) -> Text:
        self.clear_costmaps()
        return Text("cleared")

    # ------------------------------------------------------------ actions
    def resolve(self, goal: NavigateGoal) -> Target:
        if goal.pose is not None and goal.place:
            raise ActionAborted("give a place or a pose, not both")
        if goal.pose is not None:
            p = goal.pose
            if not all(math.isfinite(v) for v in (p.x, p.y, p.theta)):
                raise ActionAborted("the goal pose is not a finite number")
            return Target("", "the goal", (p.x, p.y, p.theta))
        if not goal.place.strip():
            raise ActionAborted("no place or pose given")
        place: Place | None = self.data.places.resolve(goal.place)
        if place is None:
            known = ", ".join(self.data.places.names()) or "none"
            raise ActionAborted(f"I don't know a place called '{goal.place}' (places: {known})")
        spoken = place.name.replace("_", " ").lower()
        return Target(place.name, spoken, place.pose.as_tuple())

    async def _end_goal(self, action: str) -> bool:
        """Cancel the running goal of ``action`` and wait (bounded) for it; False when none ran."""
        handle = self.bus.actions.active(action)
        if handle is None:
            return False
        try:
            await handle.cancel()
        except GoalTimeout:
            self.log.error("a navigation goal did not wind down after its cancel", action=action)
        return True

    async def _navigate(self, goal: NavigateGoal, ctx: GoalContext) -> NavigateResult:
        await self._end_goal(topics.TOUR)  # a new goal from outside ends a running tour
        target = self.resolve(goal)
        return await self.drive_to(target, ctx.feedback)

    async def drive_to(self, target: Target, feedback: Any) -> NavigateResult:
        self.goals += 1
        run = self._run = GoalRun(self, target, feedback)
        try:
            return await run.execute()
        finally:
            self.stop()
            if self._run is run:  # not already replaced by a preempting goal
                self._run = None
                self.set_state(IDLE)

    async def _tour(self, goal: TourGoal, ctx: GoalContext) -> TourResult:
        await self._end_goal(topics.NAVIGATE_TO)
        if not 0 <= goal.start_index <= len(goal.places):
            raise ActionAborted(f"start_index {goal.start_index} is outside the tour of {len(goal.places)}")
        completed: list[str] = []
        targets = [self.resolve(NavigateGoal(place=p)) for p in goal.places]
        for i in range(goal.start_index, len(targets)):
            t = targets[i]

            def relay(fb: NavigateFeedback, i: int = i, t: Target = t) -> None:
                ctx.feedback(TourFeedback(i, t.name, fb.state))

            result = await self.drive_to(t, relay)
            if not result.succeeded:
                why = f"stopped at stop {i + 1} ({t.name}): {result.reason}"
                return TourResult(tuple(completed), False, why)
            completed.append(t.name)
            ctx.feedback(TourFeedback(i, t.name, NavState.IDLE))
            if i < len(targets) - 1:
                await self.clock.sleep(goal.dwell_s)
        return TourResult(tuple(completed), True)

    def stats(self) -> dict[str, Any]:
        return {"goals": self.goals, "commands": self.commands}
