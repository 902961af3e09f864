"""Social behaviour while driving one goal (issue #20): the people tracker fed from the scans,
the speed cap near people, pulling over for a crowd in a narrow corridor, and planning that
keeps right and goes around groups. The rules are :mod:`sage_robot.nav.social`; the goal's
control loop (:mod:`sage_robot.nav.drive`) calls in here.

Events on ``/sage/events`` (each kind at most every ``SOCIAL_EVENT_AGAIN_S`` on one goal):
``slowing_for_people``, ``pulling_over``, ``passing_group``. The "excuse me" of a robot
that is stopped by people is the drive's ``blocked_by_people`` (once, then wait).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from sage_robot.core.msgs.nav import NavState
from sage_robot.nav.controller import Command, ControllerParams, PurePursuit
from sage_robot.nav.people_track import PeopleTracker, Track, groups, person_blobs, scan_points
from sage_robot.nav.planner import PATH_SPACING_M, NoPath, Plan, plan
from sage_robot.nav.social import (
    group_marks,
    keep_right,
    nearest_person_m,
    people_speed_cap,
    should_pull_over,
    still_coming,
)

if TYPE_CHECKING:
    from sage_robot.nav.costmap import Costmap
    from sage_robot.nav.drive_host import DriveHost

Pose = tuple[float, float, float]

SOCIAL_EVENT_AGAIN_S = 15.0  # one social event kind at most this often on one goal (s)
PULL_OVER_SIDE_MAX_M = 1.0  # the robot moves at most this far to the right to pull over (m)
PULL_OVER_WALL_GAP_M = 0.1  # and stops this far beyond its inscribed radius from the wall (m)
PULL_OVER_MIN_SIDE_M = 0.1  # less room than this to the right: it just stops where it is (m)
PULL_OVER_AHEAD_M = 1.0  # the robot is aside after this much forward travel (m) ...
PULL_OVER_RUNOUT_M = 1.5  # ... and its path goes on parallel this far (so the carrot stays ahead) (m)
PULL_OVER_LOOKAHEAD_M = 0.6  # a short carrot: the robot gets aside, not just a little aside (m)
PULL_OVER_TOLERANCE_M = 0.05  # aside when this near the intended sideways offset (m)
PULL_OVER_MOVE_S = 8.0  # bound on moving to the pull-over point (s)
PULL_OVER_WAIT_S = 20.0  # bound on waiting there for the crowd to pass (s)
PULL_OVER_CLEAR_S = 1.0  # nobody coming head-on this long: the crowd has passed (s)
PULL_OVER_AGAIN_S = 10.0  # after pulling over, not again for this long (s)
WATCH_PERIOD_S = 0.2  # how often the crowd is looked at while pulled over (s)
GROUP_EVENT_WITHIN_M = 4.0  # a plan made with a group this near says "passing_group" (m)


class Social:
    """One goal's social behaviour for ``node`` (a :class:`~sage_robot.nav.drive_host.DriveHost`)."""

    def __init__(self, node: DriveHost, params: ControllerParams, dt: float) -> None:
        self.node, self.params, self.dt = node, params, dt
        self.tracker = PeopleTracker()
        self.tracks: list[Track] = []
        self._scan_stamp: float | None = None
        self._said: dict[str, float] = {}  # event kind -> when last published (clock s)
        self._pull_again_at = -math.inf
        self.pulled_over = 0  # times the robot pulled over on this goal

    # ------------------------------------------------------------ seeing people
    def observe(self) -> list[Track]:
        """Feed the latest scan (once per scan) to the tracker; → the live tracks."""
        node = self.node
        scan, pose = node.scan, node.pose()
        if scan is None or pose is None or scan.stamp == self._scan_stamp:
            return self.tracks
        self._scan_stamp = scan.stamp
        lidar = node.settings.robot.lidar
        points = scan_points(pose, (lidar.x_m, lidar.y_m, lidar.yaw_rad), scan)
        self.tracks = self.tracker.update(scan.stamp, person_blobs(points, node.global_cm))
        return self.tracks

    def snapshot(self) -> list[Track]:
        """A copy of the tracks for a planning job (taken on the event loop)."""
        return [dataclasses.replace(k) for k in self.tracks]

    def say(self, kind: str, message: str, place: str = "") -> None:
        now = self.node.clock.now()
        if now - self._said.get(kind, -math.inf) >= SOCIAL_EVENT_AGAIN_S:
            self._said[kind] = now
            self.node.event(kind, message, place=place)

    # ------------------------------------------------------------ slowing down
    def regulate(self, cmd: Command, pose: Pose) -> Command:
        """``cmd`` with its speed capped by the nearest tracked person (the arc kept)."""
        cap = people_speed_cap(nearest_person_m(pose, self.tracks))
        if cmd.v <= cap:
            return cmd
        self.say("slowing_for_people", "slowing down: people close by")
        scale = cap / cmd.v
        return dataclasses.replace(cmd, v=cap, w=cmd.w * scale)

    # ------------------------------------------------------------ pulling over
    def pull_over_due(self, pose: Pose) -> bool:
        return self.node.clock.now() >= self._pull_again_at and \
            should_pull_over(self.node.global_cm, pose, self.tracks)

    async def pull_over(self, feedback: Callable[[NavState], None]) -> None:
        """Move to the right wall, stop, and wait until nobody comes head-on (bounded)."""
        node, clock = self.node, self.node.clock
        self.pulled_over += 1
        self.say("pulling_over", "let me make room for you to pass")
        feedback(NavState.WAITING_FOR_PEOPLE)
        pose = node.pose()
        cm = node.local_cm
        if pose is not None and cm is not None:
            side = _room_to_the_right(cm, pose)
            if side >= PULL_OVER_MIN_SIDE_M:
                await self._move_aside(pose, side)
        node.stop()
        t0 = clear_since = clock.now()
        while clock.now() - t0 < PULL_OVER_WAIT_S:
            await clock.sleep(WATCH_PERIOD_S)
            now, pose = clock.now(), node.pose()
            if pose is not None and still_coming(pose, self.observe()):
                clear_since = now
            elif now - clear_since >= PULL_OVER_CLEAR_S:
                break
        self._pull_again_at = clock.now() + PULL_OVER_AGAIN_S
        node.log.info("pulled over for people", waited_s=round(clock.now() - t0, 1))
        feedback(NavState.DRIVING)

    async def _move_aside(self, pose: Pose, side: float) -> None:
        """Follow a smooth path that ends ``side`` to the right, parallel to the heading, until
        the robot is that far to the right (bounded by PULL_OVER_MOVE_S and the forward check)."""
        x, y, th = pose
        c, s = math.cos(th), math.sin(th)
        along = np.arange(0.0, PULL_OVER_AHEAD_M + PULL_OVER_RUNOUT_M + 1e-9, PATH_SPACING_M)
        u = np.clip(along / PULL_OVER_AHEAD_M, 0.0, 1.0)
        lateral = side * u * u * (3.0 - 2.0 * u)  # smoothstep: leaves and ends parallel
        path = np.column_stack((x + along * c + lateral * s, y + along * s - lateral * c))
        ctl = PurePursuit(path, dataclasses.replace(self.params, lookahead_m=PULL_OVER_LOOKAHEAD_M), th)
        node, clock = self.node, self.node.clock
        t_end = clock.now() + PULL_OVER_MOVE_S
        while clock.now() < t_end:
            here = node.pose()
            if here is None or (here[0] - x) * s - (here[1] - y) * c >= side - PULL_OVER_TOLERANCE_M:
                break
            cmd = ctl.step(here, node.local_cm)
            if cmd.arrived or cmd.blocked:
                break
            cmd = self.regulate(cmd, here)
            node.command(cmd.v, cmd.w)
            await clock.sleep(self.dt)
        node.stop()

    # ------------------------------------------------------------ planning
    def plan(self, cm: Costmap, start: tuple[float, float], goal: tuple[float, float],
             tracks: list[Track]) -> Plan:
        """A plan that goes around groups (when there is a way) and keeps right. Runs in the
        planning thread, on ``tracks`` taken on the event loop."""
        marks = group_marks(cm, tracks) & ~cm.static
        result = None
        if marks.any():
            saved = cm.obstacles.copy()
            cm.obstacles |= marks
            cm.refresh()
            try:
                result = plan(cm, start, goal)
            except NoPath:
                result = None  # no way around the group: through it (people make way)
            finally:
                cm.obstacles[:] = saved
                cm.refresh()
        return keep_right_plan(result if result is not None else plan(cm, start, goal), cm)


def keep_right_plan(p: Plan, cm: Costmap) -> Plan:
    points = keep_right(p.points, cm)
    return Plan(points, float(np.hypot(*np.diff(points, axis=0).T).sum()) if len(points) > 1 else 0.0)


def group_ahead(pose: Pose, tracks: list[Track], within_m: float) -> bool:
    """Whether a group of people stands or walks ahead of the robot, within ``within_m``."""
    x, y, th = pose
    c, s = math.cos(th), math.sin(th)
    return any(c * (k.x - x) + s * (k.y - y) > 0.0 and math.hypot(k.x - x, k.y - y) <= within_m
               for g in groups(tracks) for k in g)


def _room_to_the_right(cm: Costmap, pose: Pose) -> float:
    """How far (m) the robot can move to its right, keeping PULL_OVER_WALL_GAP_M beyond its
    inscribed radius from the map's walls and outside the inscribed radius of anything the scan
    sees (at most PULL_OVER_SIDE_MAX_M)."""
    x, y, th = pose
    s = np.arange(1, round(PULL_OVER_SIDE_MAX_M / PATH_SPACING_M) + 1) * PATH_SPACING_M
    pts = np.column_stack((x + s * math.sin(th), y - s * math.cos(th)))
    ok = (cm.wall_distance(pts) >= cm.inscribed_m + PULL_OVER_WALL_GAP_M) & ~cm.blocked(pts)
    bad = np.flatnonzero(~ok)
    n = int(bad[0]) if len(bad) else len(s)
    return float(s[n - 1]) if n else 0.0
