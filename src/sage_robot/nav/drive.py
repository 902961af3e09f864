"""Driving one goal: plan, follow, replan, recover — the behaviour tree of Nav2 in plain code.

Recoveries run in order, each once, when the robot is blocked (no plan, or the forward
collision check stops it); moving ``PROGRESS_RESET_M`` resets the ladder, and a goal that gets
no ``PROGRESS_M`` closer than ever before for ``NO_PROGRESS_S`` is given up with its reason:

1. clear the costmaps and replan;
2. wait for people: publish an Event ``blocked_by_people`` (the voice says "excuse me"),
   stop, and watch the intended path for up to ``nav.people_wait_s``; go on once it is free
   (in the global costmap and for the controller's forward check); stopped again before
   getting anywhere, it goes on waiting with what is left of the time;
3. replan around whatever is still there;
4. spin in place (a full turn refreshes the costmaps), replan;
5. abort with a reason that is true (:meth:`GoalRun._why_blocked`): people (what blocks the
   way moved while the robot watched, or is person-sized), an obstacle that is not on the
   map (it stood still and is bigger than a person), or a closed passage (no way even on
   the map: said at once, nothing is waited for).

People (issue #20, :mod:`sage_robot.nav.social_drive`): the robot slows down near them,
keeps right, plans around groups, and pulls over for a crowd in a narrow corridor.

Where ``robot.allow_reverse`` is true, a robot stopped close in front of an obstacle first
backs off (at most ``BACKUP_M``, slowly, only onto floor that is clear behind it).

Before each rung, a robot that stands within the inscribed radius of an obstacle, or barely
beyond it (the forward check stops every arc that gets closer or grazes it, and it never
reverses), first turns toward open floor and creeps clear (at most ``STEP_AWAY_M``).

From step 3 on (waiting for people has failed), a robot within ``SETTLE_NEAR_GOAL_M`` of
a goal that the latest scan shows something standing on settles there instead (succeeded,
with a note that says what stands at the spot); with nothing there it climbs on.

When localization is lost: stop, Event ``lost``, global relocalization while spinning
slowly; if health does not come back within ``nav.relocalize_timeout_s``, Event
``help_needed`` and abort. Time comes only from the node's clock; planning runs in a
worker thread.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy import ndimage

from sage_robot.core import topics
from sage_robot.core.actions import ActionAborted
from sage_robot.core.errors import ServiceError
from sage_robot.core.geometry import wrap_angle
from sage_robot.core.msgs import Text
from sage_robot.core.msgs.nav import NavigateFeedback, NavigateResult, NavState
from sage_robot.nav.blockers import goal_taken
from sage_robot.nav.controller import ControllerParams, PurePursuit, escape_heading
from sage_robot.nav.planner import PATH_SPACING_M, NoPath, Plan, path_blocked, plan
from sage_robot.nav.social_drive import GROUP_EVENT_WITHIN_M, Social, group_ahead, keep_right_plan

if TYPE_CHECKING:
    from sage_robot.nav.costmap import Costmap
    from sage_robot.nav.drive_host import DriveHost

LOCALIZED_WAIT_S = 10.0  # wait this long for a first pose before giving up
GUARD_BLOCKED_S = 2.0  # the collision guard holding the robot this long blocks the way (s)
PROGRESS_RESET_M = 1.0  # driving this far after a recovery resets the recovery ladder
# A goal that has not got PROGRESS_M closer to its goal than ever before (along its path, or in
# a straight line) for NO_PROGRESS_S (or 5 x nav.people_wait_s, if longer) is given up, with
# the reason the ladder knows: in a crowd the ladder reset whenever the robot had moved a metre,
# and on the TurtleBot sandbox a robot drove to and fro between two routes round the pillars for
# 300 s (issue #20). Each new best is a metre nearer, so a goal's time is bounded. (120 s and
# 180 s cut legs there that would have arrived: some took 226-280 s among five people.)
PROGRESS_M = 1.0
NO_PROGRESS_S = 300.0
CLEAR_SETTLE_S = 0.5  # after clearing the costmaps, let fresh scans come in (s)
PLAN_DROP_WAIT_S = 5.0  # bound on waiting for a plan in flight when a drive ends (s)
PLAN_LATENCY_S = 0.25  # time a plan may take (a Jetson's planner on a building map, as Nav2's
#   planner server replans while the controller follows the previous path): in the simulator
#   the robot drives on beside it and the plan arrives exactly this much later (s)
EXCUSE_ME_AGAIN_S = 30.0  # "excuse me" at most this often on one goal: once, then wait (s)
WATCH_PERIOD_S = 0.5  # how often the intended path is checked while waiting for people (s)
WATCH_AHEAD_M = 8.0  # how much of the intended path must be free to go on (m)
SPIN_SPEED_RADPS = 0.6
RELOC_SPIN_RADPS = 0.4
LOST_CONFIRM_S = 1.0  # health must say "lost" this long before the robot stops (s)
RELOCALIZED_CONFIRM_S = 2.0  # and fit well this long to count as relocalized (s)
RELOCALIZED_SCORE = 0.75  # health score needed to count as relocalized (0..1)
RELOCALIZED_SPREAD_M = 0.5  # and the particle cloud must have shrunk to this (m)
ETA_MIN_SPEED_MPS = 0.3
SETTLE_NEAR_GOAL_M = 3.5  # with the goal itself taken by people, this close counts as arrived (m);
#   a standing person stops the robot 2.4-3.1 m away (legs padding, inscribed radius, forward check)
GOAL_TAKEN_CLEAR_M = 1.0  # people on the goal: plan as if this much around it were free (m)
KEEP_PATH_RATIO = 0.85  # switch to a fresh plan only if it is this much shorter than the rest...
SWITCH_BLOCKED_AHEAD_M = 2.0  # ... or the path is blocked this near ahead (m): farther off, a mark
#   seen from here and lost from there (a person behind a pillar) flipped the plan between
#   three routes every second, and the robot never got anywhere (issue #20, the sandbox)
STEP_AWAY_M = 0.5  # longest step away from an obstacle the robot stands too close to (m)
STEP_AWAY_CLEAR_M = 0.05  # step away until this much beyond the inscribed radius (m)
STEP_AWAY_SPEED_MPS = 0.15
STEP_AWAY_TURN_RADPS = 0.6
STEP_AWAY_ALIGNED_RAD = 0.1  # turned toward the escape heading within this (rad)
STEP_AWAY_SLACK = 3.0  # time allowed: this many times the time the step should take
STEP_AWAY_LOOK_M = 0.1  # creeping stops when the floor this far ahead is nearer an obstacle (m)
BACKUP_M = 0.3  # longest reverse in a recovery (only where robot.allow_reverse) (m)
BACKUP_SPEED_MPS = 0.1
BACKUP_WHEN_AHEAD_M = 0.35  # back off when an obstacle is this near in front beyond the inscribed radius (m)
BACKUP_CLEAR_M = 0.05  # the floor behind must stay this much beyond the inscribed radius (m)
BLOCKER_NEAR_M = 0.5  # scan marks this near the intended path block it (m)
BLOCKER_MOVED_M = 0.15  # a blocking mark this far from every mark of the first look has moved (m)
BLOCKER_MOVED_CELLS = 3  # ... and it takes this many such cells (scan noise moves one or two)
PERSON_SIZED_M = 0.6  # a blocking blob no wider than this could be a person (m)


@dataclass(frozen=True)
class Target:
    name: str  # canonical place name, "" for a pose
    spoken: str  # how a person would say it ("the clean room")
    pose: tuple[float, float, float]


class Blocked(Exception):
    """The way ahead is blocked (no plan, or the controller stopped for an obstacle)."""


class GoalRun:
    """Drives one goal for ``node`` (anything that is a :class:`~sage_robot.nav.drive_host.DriveHost`)."""

    def __init__(self, node: DriveHost, target: Target, feedback: Callable[[Any], None]) -> None:
        self.node, self.target, self._feedback = node, target, feedback
        nav, robot = node.settings.nav, node.settings.robot
        self.params = ControllerParams(robot.max_linear_mps, robot.max_angular_radps, nav.lookahead_m,
                                       nav.xy_goal_tolerance_m, nav.yaw_goal_tolerance_rad)
        self.dt = 1.0 / nav.controller_hz
        self.clock = node.clock
        self.state = NavState.PLANNING
        self.remaining = 0.0
        self.travelled = 0.0
        self._last_xy: tuple[float, float] | None = None
        self._level = 0
        self._level_xy: tuple[float, float] | None = None
        self._best = (math.inf, math.inf)  # least path left and straight distance to the goal so far (m)
        self._best_at = 0.0  # when either last became PROGRESS_M less (clock s)
        self._waited_s = 0.0  # waited for people since the ladder last reset (s)
        self._asked_at = -math.inf  # when "excuse me" was last said on this goal (clock s)
        self._cleared = False  # the last wait ended because the path looked free
        self._first_blockers: np.ndarray | None = None  # what blocked the path at the wait's first look
        self._blocker_moved = False  # ... and whether it has moved since
        self._blocker_sizes: list[float] = []  # sizes (m) of the blobs on the path at the latest look
        self.social = Social(node, self.params, self.dt)  # people: slow down, keep right, pull over

    # ------------------------------------------------------------ small steps
    def feedback(self, state: NavState) -> None:
        self.state = state
        eta = self.remaining / max(ETA_MIN_SPEED_MPS, self.params.max_v * 0.7)
        fb = NavigateFeedback(state, self.target.name, round(self.remaining, 2), round(eta, 1))
        self.node.set_state(fb)
        self._feedback(fb)

    def _track(self, pose: tuple[float, float, float]) -> None:
        self._check_progress(pose)
        if self._last_xy is not None:
            self.travelled += math.hypot(pose[0] - self._last_xy[0], pose[1] - self._last_xy[1])
        self._last_xy = (pose[0], pose[1])
        if self._level and self._level_xy is not None and \
                math.hypot(pose[0] - self._level_xy[0], pose[1] - self._level_xy[1]) > PROGRESS_RESET_M:
            self._level, self._level_xy = 0, None
            self._waited_s, self._cleared = 0.0, False

    def _check_progress(self, pose: tuple[float, float, float]) -> None:
        """Note a new best (PROGRESS_M nearer the goal); raise ActionAborted after NO_PROGRESS_S
        without one."""
        gx, gy, _ = self.target.pose
        left = self.remaining if self.remaining > 0.0 else math.inf  # (no path followed yet)
        straight = math.hypot(pose[0] - gx, pose[1] - gy)
        now = self.clock.now()
        if left < self._best[0] - PROGRESS_M or straight < self._best[1] - PROGRESS_M or \
                self._best[1] == math.inf:
            self._best, self._best_at = (min(left, self._best[0]), min(straight, self._best[1])), now
        elif now - self._best_at > (limit := max(NO_PROGRESS_S, 5.0 * self.node.settings.nav.people_wait_s)):
            raise ActionAborted(f"{self._why_blocked()} (I got no closer in {limit:.0f} s)")

    def pose(self) -> tuple[float, float, float]:
        pose = self.node.pose()
        if pose is None:
            raise ActionAborted("I don't know where I am yet")
        return pose

    async def _plan(self, with_obstacles: bool = True) -> Plan:
        node, start = self.node, self.pose()
        goal = self.target.pose[:2]
        scan = node.scan  # the job's inputs are taken here, not read from the node in the thread
        local = node.local_cm
        tracks = self.social.snapshot()

        def work() -> Plan:
            cm = node.global_cm
            if with_obstacles:
                node.refresh_global(start, scan)
                try:
                    with cm.impassable_as(local):  # never through what the controller stops at
                        return self.social.plan(cm, start[:2], goal, tracks)
                except NoPath:
                    if not cm.blocked(np.array([goal]))[0]:
                        raise
            # without the scan's marks (or, when people stand on the goal, without those near
            # it: the robot heads there, the forward check stops it short, and the ladder
            # settles once waiting has failed)
            saved = cm.obstacles.copy()
            if with_obstacles:
                cm.clear_obstacles_near(goal[0], goal[1], GOAL_TAKEN_CLEAR_M)
            else:
                cm.clear_obstacles()
            try:
                return keep_right_plan(plan(cm, start[:2], goal), cm)
            finally:
                cm.obstacles[:] = saved
                cm.refresh()

        try:
            result = await self.clock.offload(work, latency_s=PLAN_LATENCY_S)
        except NoPath as exc:
            raise Blocked(str(exc)) from None
        if with_obstacles and group_ahead(start, tracks, GROUP_EVENT_WITHIN_M):
            self.social.say("passing_group", "going around the group, not through it")
        node.publish_plan(result.points)
        return result

    # ------------------------------------------------------------ the goal
    async def execute(self) -> NavigateResult:
        t0 = self.clock.now()
        await self._wait_localized()
        while True:
            try:
                await self._drive()
                return NavigateResult(True, self.target.name, "", round(self.travelled, 2),
                                      round(self.clock.now() - t0, 2))
            except Blocked as exc:
                self.node.stop()
                near = await self._recover(str(exc))
                if near:
                    return NavigateResult(True, self.target.name, near, round(self.travelled, 2),
                                          round(self.clock.now() - t0, 2))

    async def _wait_localized(self) -> None:
        deadline = self.clock.now() + LOCALIZED_WAIT_S
        while self.node.pose() is None:
            if self.clock.now() >= deadline:
                raise ActionAborted("I don't know where I am: localization has not started")
            await self.clock.sleep(self.dt)

    async def _drive(self) -> None:
        """Plan and follow until arrival; raises Blocked."""
        if self.node.lost():
            await self._relocalize()
        self.feedback(NavState.PLANNING)
        current = await self._plan()
        ctl = PurePursuit(current.points, self.params, self.target.pose[2])
        replan_period = 1.0 / self.node.settings.nav.replan_hz
        next_replan = self.clock.now() + replan_period
        lost_since: float | None = None
        guard_since: float | None = None  # since when the collision guard has held the robot
        self.feedback(NavState.DRIVING)
        replan: asyncio.Future[Plan] | None = None
        try:
            while True:
                now = self.clock.now()
                lost_since = await self._watch_lost(now, lost_since)
                pose = self.pose()
                self._track(pose)
                cmd = ctl.step(pose, self.node.local_cm)
                if cmd.arrived:
                    self.node.stop()
                    self.node.event("arrived", f"arrived at {self.target.spoken}", place=self.target.name)
                    return
                if cmd.blocked:
                    raise Blocked("an obstacle is in the way")
                self.social.observe()
                if self.social.pull_over_due(pose):  # a crowd head-on in a narrow corridor
                    await self.social.pull_over(self.feedback)
                    continue
                cmd = self.social.regulate(cmd, pose)
                guard_since = _guard_hold(now, cmd.v, self.node.command(cmd.v, cmd.w), guard_since)
                self.remaining = ctl.remaining_m()
                if replan is not None and replan.done():
                    fresh, replan = replan.result(), None  # raises Blocked when there is no way now
                    if self._switch(ctl, fresh):
                        current, ctl = fresh, PurePursuit(fresh.points, self.params, self.target.pose[2])
                if now >= next_replan and replan is None:
                    next_replan = now + replan_period
                    self.feedback(NavState.DRIVING)
                    if not self._near_goal(pose):  # planned beside the control loop, as Nav2's server
                        replan = asyncio.ensure_future(self._plan())
                await self.clock.sleep(self.dt)
        finally:
            if replan is not None:
                await self._drop_plan(replan)

    async def _drop_plan(self, replan: asyncio.Future[Plan]) -> None:
        """A plan still in flight is let finish, then dropped: its thread changes the global
        costmap, and the next plan or path check must not run beside it."""
        with contextlib.suppress(Exception):  # a Blocked nobody needs any more
            await self.clock.wait_for(asyncio.shield(replan), PLAN_DROP_WAIT_S)

    async def _watch_lost(self, now: float, lost_since: float | None) -> float | None:
        """Since when localization has said "lost" (None: it does not); lost for
        LOST_CONFIRM_S: relocalize and raise Blocked, to replan from the new pose."""
        if not self.node.lost():
            return None
        lost_since = now if lost_since is None else lost_since
        if now - lost_since >= LOST_CONFIRM_S:
            await self._relocalize()
            raise Blocked("relocalized")
        return lost_since

    def _switch(self, ctl: PurePursuit, fresh: Plan) -> bool:
        """Keep following the current path while it is free for the next
        :data:`SWITCH_BLOCKED_AHEAD_M` and not much longer than the fresh one (so the robot does
        not flip sides around a person at every replan, nor between routes round pillars that
        hide a person from one pose and show them from the next)."""
        rest = ctl.path[ctl._i:]
        if path_blocked(self.node.global_cm, rest, SWITCH_BLOCKED_AHEAD_M):
            return True
        return fresh.length_m < KEEP_PATH_RATIO * ctl.remaining_m()

    def _near_goal(self, pose: tuple[float, float, float]) -> bool:
        gx, gy, _ = self.target.pose
        return math.hypot(pose[0] - gx, pose[1] - gy) < self.params.lookahead_m

    # ------------------------------------------------------------ recoveries
    async def _recover(self, why: str) -> str:
        """One rung of the ladder. Returns a note when the robot should settle for where it is
        (the goal itself is taken and it stands close by); raises ActionAborted at the top."""
        if why == "relocalized":
            return ""
        pose = self.pose()
        self._check_progress(pose)
        self._level_xy = (pose[0], pose[1])
        level, self._level = self._level, self._level + 1
        if level == 2 and self._cleared and self._waited_s < self.node.settings.nav.people_wait_s:
            # the path looked free, yet the robot was stopped again before it got anywhere (the
            # person is still close ahead): go on waiting with what is left of the time
            level, self._level = 1, 2
        if level >= 2:  # people were waited for and did not leave: settle if the goal is right there
            note = await self._settle_note(pose)
            if note:
                return note
        self.feedback(NavState.RECOVERING)
        await self._step_away()
        await self._back_off()
        if level == 0:
            self.node.clear_costmaps()
            await self.clock.sleep(CLEAR_SETTLE_S)
        elif level == 1:
            await self._wait_for_people()
        elif level == 2:
            pass  # replan around: the next _drive plans with everything the scans show now
        elif level == 3:
            await self._spin(2 * math.pi, SPIN_SPEED_RADPS)
        else:
            raise ActionAborted(self._why_blocked())
        return ""

    def _why_blocked(self) -> str:
        """Why the robot gives up, as it saw it: people when something is on the intended path
        at the last look and what blocked it moved while it watched; an obstacle not on the
        map when it stood still and is bigger than a person; an obstacle or someone standing
        still when it stood still and is person-sized (a box's face and a person's legs look
        alike to a lidar); where it could not get on when nothing is on the path."""
        where = f"to {self.target.spoken}" if self.target.name else "to the goal"
        sizes = self._blocker_sizes
        if sizes and not self._blocker_moved:
            waited = f" (I watched it {self._waited_s:.0f} s: it did not move)" \
                if self._waited_s >= 1.0 else ""
            if max(sizes) > PERSON_SIZED_M:
                return (f"the way {where} is blocked by an obstacle that is not on the map, about "
                        f"{max(sizes):.1f} m across{waited}; I found no way around it")
            if self._waited_s >= 1.0:  # as small as a person, and it stood still: either
                return (f"the way {where} is blocked by something not on the map, about "
                        f"{max(sizes):.1f} m across: an obstacle, or someone standing still{waited}; "
                        "I found no way around it")
        if sizes:  # on the path at the last look, and it moved while the robot watched: people
            waited = f"I waited {self._waited_s:.0f} s for people to step aside and " \
                if self._waited_s >= 1.0 else "people are in the way and "
            return f"the way {where} is blocked: {waited}found no way around"
        # Nothing on the path at the last look (whatever moved during the wait has gone): the
        # robot could not get on; not people.
        x, y, _ = self.pose()
        still = "" if self._blocker_moved else ", nothing there moved,"
        return (f"the way {where} is blocked: I could not get past ({x:.1f}, {y:.1f}){still} "
                "and I found no way around")

    async def _settle_note(self, pose: tuple[float, float, float]) -> str:
        """Within SETTLE_NEAR_GOAL_M of a goal that something the scan sees stands on: arrive
        there, with a note that says what stands there. Checked as soon as waiting for people has
        failed, so the robot cannot shuttle back and forth near the goal (moving resets the
        recovery ladder). Nothing on the spot, no settling: the ladder goes on (issue #20: on a
        1.45 m wide floor every stop was within reach of the goal and said "someone is standing
        at the spot" with nobody there)."""
        gx, gy, _ = self.target.pose
        short = math.hypot(pose[0] - gx, pose[1] - gy)
        if short > SETTLE_NEAR_GOAL_M:
            return ""
        size = await self.clock.offload(self._goal_taken, pose, self.node.scan)
        if size is None:
            return ""
        self.node.event("arrived", f"arrived near {self.target.spoken}", place=self.target.name)
        if size <= PERSON_SIZED_M:
            return f"stopped {short:.1f} m short: someone is standing at the spot"
        return (f"stopped {short:.1f} m short: something not on the map, about {size:.1f} m across, "
                "stands at the spot")

    def _goal_taken(self, pose: tuple[float, float, float], scan: Any) -> float | None:
        """What the latest scan shows on the goal (:func:`blockers.goal_taken`). Runs in a
        worker thread, its inputs taken on the event loop."""
        cm = self.node.global_cm
        cm.clear_obstacles()
        self.node.refresh_global(pose, scan)
        return goal_taken(cm, self.target.pose[:2])

    async def _wait_for_people(self) -> None:
        """Stop, say so, and watch the intended (obstacle-free) path until it clears."""
        node = self.node
        node.stop()
        self._cleared = False  # (an early return below must let the ladder climb on)
        try:
            intended = await self._plan(with_obstacles=False)
        except Blocked as exc:
            where = f"to {self.target.spoken}" if self.target.name else "to the goal"
            raise ActionAborted(f"the way {where} is closed on the map: there is no passage I fit "
                                f"through ({exc})") from None
        self._first_blockers, self._blocker_moved, self._blocker_sizes = None, False, []
        self.feedback(NavState.WAITING_FOR_PEOPLE)
        now = self.clock.now()
        if now - self._asked_at >= EXCUSE_ME_AGAIN_S:  # once, then wait (not at every retry)
            self._asked_at = now
            node.event("blocked_by_people", "excuse me, may I pass?", place=self.target.name)
        t0, before = self.clock.now(), self._waited_s
        wait_s = node.settings.nav.people_wait_s - before
        while self.clock.now() - t0 < wait_s:
            await self.clock.sleep(WATCH_PERIOD_S)
            self._waited_s = before + self.clock.now() - t0
            if await self.clock.offload(self._path_free, intended.points, self.node.pose(),
                                        self.node.scan, self.node.local_cm):
                node.event("path_clear", "thank you", place=self.target.name)
                self._cleared = True
                return

    def _path_free(self, points: np.ndarray, pose: tuple[float, float, float] | None, scan: Any,
                   local: Costmap | None) -> bool:
        """Whether the intended path, from the robot on, is free in the global costmap as the
        latest scan shows it, and the controller's forward check on the local costmap would let
        the robot start. Runs in a worker thread.

        Older scan marks are dropped first: a standing robot's beams always take the same
        lines, so a passer-by marked between two of them (beams 1 degree apart are 5 cm apart
        at 3 m) would never be cleared and would hold the robot for the whole wait."""
        node = self.node
        if pose is None:
            return False
        node.global_cm.clear_obstacles()
        node.refresh_global(pose, scan)
        d = np.hypot(points[:, 0] - pose[0], points[:, 1] - pose[1])
        ahead = points[int(np.argmin(d)):]
        ahead = ahead[np.hypot(ahead[:, 0] - pose[0], ahead[:, 1] - pose[1]) > self.params.xy_tolerance_m]
        self._look_at_blockers(node.global_cm, ahead, pose)
        if path_blocked(node.global_cm, ahead, WATCH_AHEAD_M):
            return False
        return len(ahead) < 2 or local is None or \
            not PurePursuit(ahead, self.params, self.target.pose[2]).step(pose, local).blocked

    def _look_at_blockers(self, cm: Costmap, ahead: np.ndarray, pose: tuple[float, float, float]) -> None:
        """Note what the scan marks on the first WATCH_AHEAD_M of the intended path: the sizes of
        its blobs, and whether it moved since the wait's first look."""
        res = cm.geom.resolution
        pts = ahead[:max(1, int(WATCH_AHEAD_M / PATH_SPACING_M))]
        k = max(1, round(BLOCKER_NEAR_M / res))
        r, c = cm.geom.to_cell(pts[:, 0], pts[:, 1]) if len(pts) else cm.geom.to_cell(pose[0], pose[1])
        r, c = np.atleast_1d(r), np.atleast_1d(c)
        m = k + round(PERSON_SIZED_M / res) + 4  # the window: the path, the blobs on it, their extent
        r0, c0 = max(int(r.min()) - m, 0), max(int(c.min()) - m, 0)
        r1, c1 = min(int(r.max()) + m + 1, cm.geom.shape[0]), min(int(c.max()) + m + 1, cm.geom.shape[1])
        obstacles = np.zeros(cm.geom.shape, dtype=bool)
        # hits on the map's walls are those walls (range noise), not something in the way
        obstacles[r0:r1, c0:c1] = cm.obstacles[r0:r1, c0:c1] & ~cm.wall_zone[r0:r1, c0:c1]
        near = np.zeros(cm.geom.shape, dtype=bool)
        ok = cm.geom.inside(r, c)
        near[r[ok], c[ok]] = True
        near[r0:r1, c0:c1] = ndimage.binary_dilation(
            near[r0:r1, c0:c1], structure=np.hypot(*np.mgrid[-k:k + 1, -k:k + 1]) <= k)
        marks = obstacles & near
        labels = np.zeros(cm.geom.shape, dtype=np.int32)
        labels[r0:r1, c0:c1] = ndimage.label(ndimage.binary_dilation(obstacles[r0:r1, c0:c1], iterations=2),
                                             structure=np.ones((3, 3)))[0]
        on_path = np.unique(labels[marks])
        self._blocker_sizes = []
        for i, sl in enumerate(ndimage.find_objects(labels), start=1):
            if sl is not None and i in on_path:
                self._blocker_sizes.append(
                    (max(sl[0].stop - sl[0].start, sl[1].stop - sl[1].start) - 4) * res)
        if self._first_blockers is None:
            self._first_blockers = marks.copy()
            return
        tol = max(1, round(BLOCKER_MOVED_M / res))
        for a, b in ((marks, self._first_blockers), (self._first_blockers, marks)):
            far = a & ~ndimage.binary_dilation(b, iterations=tol) if b.any() else a
            if int(far.sum()) >= BLOCKER_MOVED_CELLS:
                self._blocker_moved = True

    async def _step_away(self) -> None:
        """Standing within the inscribed radius of an obstacle, or less than STEP_AWAY_CLEAR_M
        beyond it (every arc toward the path gets closer, or grazes the radius round a
        pillar's corner, so the forward check stops it, and the robot never reverses): turn
        toward the heading that leads away, and creep until STEP_AWAY_CLEAR_M clear, at most
        STEP_AWAY_M."""
        node, pose = self.node, self.pose()
        cm = node.local_cm
        if cm is None or cm.distance_at(pose[0], pose[1]) >= cm.inscribed_m + STEP_AWAY_CLEAR_M:
            return
        gx, gy, _ = self.target.pose
        heading = escape_heading(cm, pose, STEP_AWAY_M, math.atan2(gy - pose[1], gx - pose[0]))
        if heading is None:
            return
        budget_s = STEP_AWAY_SLACK * (math.pi / STEP_AWAY_TURN_RADPS + STEP_AWAY_M / STEP_AWAY_SPEED_MPS)
        t_end = self.clock.now() + budget_s
        while abs(err := wrap_angle(heading - self.pose()[2])) > STEP_AWAY_ALIGNED_RAD \
                and self.clock.now() < t_end:
            node.command(0.0, math.copysign(STEP_AWAY_TURN_RADPS, err))
            await self.clock.sleep(self.dt)
        x0, y0 = pose[0], pose[1]
        while self.clock.now() < t_end:
            x, y, th = self.pose()
            cm = node.local_cm or cm
            here = cm.distance_at(x, y)
            ahead = cm.distance_at(x + STEP_AWAY_LOOK_M * math.cos(th), y + STEP_AWAY_LOOK_M * math.sin(th))
            if here >= cm.inscribed_m + STEP_AWAY_CLEAR_M or math.hypot(x - x0, y - y0) >= STEP_AWAY_M \
                    or ahead < here - 1e-3:
                break
            node.command(STEP_AWAY_SPEED_MPS, 0.0)
            await self.clock.sleep(self.dt)
        node.stop()
        x, y, _ = self.pose()
        node.log.info("stepped away from an obstacle", moved_m=round(math.hypot(x - x0, y - y0), 2))

    async def _back_off(self) -> None:
        """Reverse slowly, at most BACKUP_M, while an obstacle is close in front and the floor
        behind stays clear (only where ``robot.allow_reverse``): room to turn and replan."""
        node = self.node
        if not node.settings.robot.allow_reverse:
            return
        x0, y0, _ = self.pose()
        t_end = self.clock.now() + STEP_AWAY_SLACK * BACKUP_M / BACKUP_SPEED_MPS
        while self.clock.now() < t_end:
            cm = node.local_cm
            if cm is None:
                break
            x, y, th = self.pose()
            c, s = math.cos(th), math.sin(th)
            front = min(cm.distance_at(x + d * c, y + d * s) for d in (0.1, 0.2, 0.3))
            back = cm.distance_at(x - 0.1 * c, y - 0.1 * s)
            if front >= cm.inscribed_m + BACKUP_WHEN_AHEAD_M or back < cm.inscribed_m + BACKUP_CLEAR_M \
                    or math.hypot(x - x0, y - y0) >= BACKUP_M:
                break
            node.command(-BACKUP_SPEED_MPS, 0.0)
            await self.clock.sleep(self.dt)
        node.stop()
        x, y, _ = self.pose()
        if math.hypot(x - x0, y - y0) > 0.01:
            node.log.info("backed off from an obstacle", moved_m=round(math.hypot(x - x0, y - y0), 2))

    async def _spin(self, angle: float, speed: float) -> None:
        turned, last = 0.0, self.pose()[2]
        t_end = self.clock.now() + angle / speed * 1.5
        while turned < angle and self.clock.now() < t_end:
            self.node.command(0.0, speed)
            await self.clock.sleep(self.dt)
            th = self.pose()[2]
            turned += abs(wrap_angle(th - last))
            last = th
        self.node.stop()

    async def _relocalize(self) -> None:
        node = self.node
        node.stop()
        self.feedback(NavState.LOST)
        node.event("lost", "I am not sure where I am; let me look around")
        try:
            await node.bus.call(topics.GLOBAL_LOCALIZATION, Text("navigator"))
        except ServiceError as exc:
            node.log.warning("global localization unavailable", error=str(exc))
        deadline = self.clock.now() + node.settings.nav.relocalize_timeout_s
        good_since: float | None = None
        await self.clock.sleep(0.5)  # let the filter take the request
        while self.clock.now() < deadline:
            node.command(0.0, RELOC_SPIN_RADPS)
            await self.clock.sleep(self.dt)
            h = node.health
            if h is None or h.lost or h.score < RELOCALIZED_SCORE or h.spread_m > RELOCALIZED_SPREAD_M:
                good_since = None
            elif good_since is None:
                good_since = self.clock.now()
            elif self.clock.now() - good_since >= RELOCALIZED_CONFIRM_S:
                node.stop()
                node.event("relocalized", "I know where I am again")
                return
        node.stop()
        node.event("help_needed", "I am lost. Could someone help me, or set my position on the map?")
        raise ActionAborted("I am lost and could not find where I am; I need help")


def _guard_hold(now: float, asked: float, sent: float, since: float | None) -> float | None:
    """Since when the collision guard (``nav/collision_guard.py``) has held the robot that the
    controller wants to move; raises Blocked once that is GUARD_BLOCKED_S (the recovery
    ladder then steps away, replans or gives up with a reason, instead of a goal that never
    ends: the TurtleBot sandbox timed out three legs in twelve without this)."""
    if asked == 0.0 or sent != 0.0:
        return None
    since = now if since is None else since
    if now - since >= GUARD_BLOCKED_S:
        raise Blocked("the scan shows something within a few centimetres ahead")
    return since
