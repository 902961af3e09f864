"""Regulated Pure Pursuit (Macenski et al. 2023; Nav2's ``RegulatedPurePursuitController``).

Each step: prune the path behind the robot, pick the carrot ``lookahead_m`` ahead (less in
tight places: down to ``MIN_LOOKAHEAD_M`` as the clearance falls, so a narrow gap's path is
followed, not cut), and steer on the arc through it (curvature ``2 y / L²`` in the robot
frame). The speed is then regulated: down on tight curves (radius below
``REGULATED_MIN_RADIUS_M``), near obstacles (clearance beyond the inscribed radius, here and up
to 0.3 m ahead, below ``COST_SCALING_DIST_M``: through a gap only 0.1 m wider than the robot it
creeps at ``MIN_REGULATED_SPEED_MPS``), near the goal, and to the speed-zone limit. When the
carrot is too far off to the side the robot rotates in place. The arc is checked
``COLLISION_HORIZON_S`` ahead on the costmap; a collision means stop and report ``blocked``
(after turning in place toward a near carrot, if the robot did not face it). Where even a short
carrot's arc cuts the bend of a gap a few centimetres wider than the robot, the robot turns in
place toward a nearer carrot and drives to it (``HUG_LOOKAHEADS_M``). The forward speed is
never negative (the seed's robot never reverses).

Conventions: map frame, metres, radians; the path is an (N, 2) array of (x, y).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sage_robot.core.geometry import wrap_angle
from sage_robot.nav.costmap import Costmap

REGULATED_MIN_RADIUS_M = 0.9  # regulated_linear_scaling_min_radius
COST_SCALING_DIST_M = 0.6  # slow down when an obstacle is nearer than this
COST_SCALING_GAIN = 1.0
CLEARANCE_AHEAD_M = (0.0, 0.15, 0.3)  # the clearance that sets the speed is taken here and ahead (m)
MIN_REGULATED_SPEED_MPS = 0.15  # regulated_linear_scaling_min_speed
APPROACH_DIST_M = 0.6  # approach_velocity_scaling_dist: slow down over the last metres
MIN_APPROACH_SPEED_MPS = 0.05
ROTATE_TO_HEADING_MIN_ANGLE_RAD = 0.785  # rotate in place when the carrot is further off than this
ROTATE_SPEED_RADPS = 0.8  # rotate_to_heading_angular_vel
ROTATE_KEEP_SIDE_RAD = 0.6  # a carrot within this of straight behind keeps the turn's direction
COLLISION_HORIZON_S = 1.0  # max_allowed_time_to_collision_up_to_carrot
COLLISION_STEP_M = 0.05
MIN_COLLISION_CHECK_M = 0.5  # look at least this far ahead, however slow the command
MIN_LOOKAHEAD_M = 0.3
CLOSE_LOOKAHEAD_M = 0.4  # fallback carrot when the full-lookahead arc would collide (m)
CLOSE_HOLD_M = 0.4  # once on the fallback carrot, keep to it for this much of the path (m)
FACE_ALIGNED_RAD = 0.15  # blocked, the robot turns toward the short carrot until this near (rad)
# Where even the short carrot's arc cuts a corner (a gap a few centimetres wider than the robot,
# bending round a pillar: the TurtleBot sandbox, issue #20), the carrot comes nearer still, to
# the first of these distances (m) the straight line to which is free, and the robot turns in
# place to face it within HUG_ALIGNED_RAD before it drives on: it then follows the path itself.
HUG_LOOKAHEADS_M = (0.3, 0.2, 0.1)
HUG_ALIGNED_RAD = 0.1
HUG_STRAIGHT_RAD = 0.03  # ... and where that arc is not free, within this to drive straight (rad)


@dataclass(frozen=True)
class Command:
    """A velocity command and why. ``blocked`` means the arc ahead runs into an obstacle."""

    v: float  # m/s, >= 0
    w: float  # rad/s, counter-clockwise
    blocked: bool = False
    arrived: bool = False
    rotating: bool = False


@dataclass(frozen=True)
class ControllerParams:
    max_v: float = 0.8
    max_w: float = 1.0
    lookahead_m: float = 1.2
    xy_tolerance_m: float = 0.25
    yaw_tolerance_rad: float = 0.25


class PurePursuit:
    """Follows one path. Stateful only in where along the path the robot last was."""

    def __init__(self, path: np.ndarray, params: ControllerParams, goal_yaw: float | None = None) -> None:
        if len(path) == 0:
            raise ValueError("empty path")
        self.path = np.asarray(path, dtype=np.float64)
        self.params = params
        self.goal_yaw = goal_yaw
        self._i = 0  # index of the closest path point so far
        self._at_goal_xy = False
        self._turn = 0.0  # the way it last rotated in place toward the carrot (+1, -1; 0 none)
        self._close_until = 0  # path index up to which the short carrot is used
        self._hug_until = 0  # ... and the nearest carrots first (HUG_LOOKAHEADS_M)
        self._hug_look: tuple[float, int] = (0.0, -1)  # the carrot distance hugged, and at which path index
        seg = np.hypot(*np.diff(self.path, axis=0).T) if len(self.path) > 1 else np.array([0.05])
        self._spacing = max(float(np.median(seg)), 1e-3)

    def remaining_m(self) -> float:
        seg = self.path[self._i:]
        return float(np.hypot(*np.diff(seg, axis=0).T).sum()) if len(seg) > 1 else 0.0

    def _prune(self, x: float, y: float) -> None:
        window = self.path[self._i:self._i + 200]
        d = np.hypot(window[:, 0] - x, window[:, 1] - y)
        self._i += int(np.argmin(d))

    def _carrot(self, x: float, y: float, lookahead: float) -> np.ndarray:
        rest = self.path[self._i:]
        d = np.hypot(rest[:, 0] - x, rest[:, 1] - y)
        beyond = np.flatnonzero(d >= lookahead)
        carrot: np.ndarray = rest[beyond[0]] if len(beyond) else rest[-1]
        return carrot

    def step(self, pose: tuple[float, float, float], costmap: Costmap | None = None) -> Command:
        """One control step at ``pose`` (map frame)."""
        p = self.params
        x, y, th = pose
        self._prune(x, y)
        goal = self.path[-1]
        dist_goal = math.hypot(goal[0] - x, goal[1] - y)
        if self._at_goal_xy or dist_goal <= p.xy_tolerance_m:
            self._at_goal_xy = True
            return self._align(th)
        if self._i < self._close_until:  # hugging the path: stay on the short carrot a while
            return self._close(pose, dist_goal, costmap)
        lookahead = max(MIN_LOOKAHEAD_M, min(self._lookahead(pose, costmap), dist_goal))
        cmd = self._pursue(pose, lookahead, dist_goal, costmap)
        if cmd.blocked:
            # the long arc cuts a corner the path goes around: hug the path with a short carrot
            # (and keep to it for CLOSE_HOLD_M, or the two carrots can turn the robot to and fro)
            self._close_until = self._i + max(1, round(CLOSE_HOLD_M / self._spacing))
            return self._close(pose, dist_goal, costmap)
        return cmd

    def _close(self, pose: tuple[float, float, float], dist_goal: float, costmap: Costmap | None) -> Command:
        """Follow the path closely: the short carrot's arc; where that cuts a corner too, the
        nearest carrots (:meth:`_hug`), and keep to them a while (CLOSE_HOLD_M: the two ways
        can turn the robot to and fro); failing both, turn toward the short carrot, or, once
        hugging, report blocked (that turn and the hug's alternated for good)."""
        hugging = self._i < self._hug_until
        cmd = Command(0.0, 0.0, blocked=True)
        if not hugging:
            cmd = self._pursue(pose, CLOSE_LOOKAHEAD_M, dist_goal, costmap)
            if not cmd.blocked or costmap is None:
                return cmd
        hug = self._hug(pose, dist_goal, costmap) if costmap is not None else None
        if hug is not None:
            self._hug_until = self._i + max(1, round(CLOSE_HOLD_M / self._spacing))
            return hug
        return cmd if hugging else self._face_if_blocked(pose, cmd)

    def _hug(self, pose: tuple[float, float, float], dist_goal: float, costmap: Costmap) -> Command | None:
        """Where the path itself is free for CLOSE_LOOKAHEAD_M: the farthest of the
        HUG_LOOKAHEADS_M carrots the straight line to which is free; turn in place to face it,
        then take the arc there, or drive straight where the arc is not free. The carrot is kept
        while the robot turns (the scan's marks change as it turns: a carrot that came and went
        turned it to and fro). None when the path is blocked or no line is free."""
        x, y, th = pose
        ahead = self.path[self._i:self._i + max(1, round(CLOSE_LOOKAHEAD_M / self._spacing)) + 1]
        if costmap.blocked(ahead).any():
            return None
        kept = self._hug_look[0] if self._hug_look[1] == self._i else None
        for look in HUG_LOOKAHEADS_M if kept is None else (kept, *HUG_LOOKAHEADS_M):
            carrot = self._carrot(x, y, look)
            if self._line_collides(pose, carrot, costmap):
                continue
            self._hug_look = (look, self._i)
            err = wrap_angle(math.atan2(carrot[1] - y, carrot[0] - x) - th)
            if abs(err) <= HUG_ALIGNED_RAD:
                cmd = self._pursue(pose, look, dist_goal, costmap)
                if not cmd.blocked:
                    return cmd
            if abs(err) > HUG_STRAIGHT_RAD:
                return Command(0.0, math.copysign(min(ROTATE_SPEED_RADPS, self.params.max_w), err),
                               rotating=True)
            return Command(self._regulate(self.params.max_v, 0.0, dist_goal, pose, costmap), 0.0)
        return None

    def _lookahead(self, pose: tuple[float, float, float], costmap: Costmap | None) -> float:
        """The carrot distance: ``lookahead_m``, shortened in tight places (clearance beyond the
        inscribed radius under ``COST_SCALING_DIST_M``) down to ``MIN_LOOKAHEAD_M`` at none, so
        the robot follows a path through a narrow gap instead of cutting its corners (as Nav2's
        lookahead shrinks with the regulated speed)."""
        full = self.params.lookahead_m
        if costmap is None:
            return full
        # where the robot stands, not ahead of it: turning in place must not move the carrot (a
        # carrot that changed with the heading turned the robot to and fro for good)
        d = costmap.distance_at(pose[0], pose[1]) - costmap.inscribed_m
        if d >= COST_SCALING_DIST_M:
            return full
        return MIN_LOOKAHEAD_M + (full - MIN_LOOKAHEAD_M) * max(d, 0.0) / COST_SCALING_DIST_M

    def _face_if_blocked(self, pose: tuple[float, float, float], cmd: Command) -> Command:
        """Blocked on the short carrot's arc while not facing it: turn in place toward it first (a
        round robot may; the straight way there can be free where the arc from here is not)."""
        if not cmd.blocked:
            return cmd
        x, y, th = pose
        carrot = self._carrot(x, y, CLOSE_LOOKAHEAD_M)
        err = wrap_angle(math.atan2(carrot[1] - y, carrot[0] - x) - th)
        if abs(err) <= FACE_ALIGNED_RAD:
            return cmd
        return Command(0.0, math.copysign(min(ROTATE_SPEED_RADPS, self.params.max_w), err), rotating=True)

    def _pursue(self, pose: tuple[float, float, float], lookahead: float, dist_goal: float,
                costmap: Costmap | None) -> Command:
        p = self.params
        x, y, th = pose
        carrot = self._carrot(x, y, lookahead)
        dx, dy = carrot[0] - x, carrot[1] - y
        c, s = math.cos(th), math.sin(th)
        lx, ly = c * dx + s * dy, -s * dx + c * dy
        angle = math.atan2(ly, lx)
        if abs(angle) > ROTATE_TO_HEADING_MIN_ANGLE_RAD:
            # a round robot can always turn where it stands; with the carrot behind it, keep the
            # way it was turning (else the sign of a carrot at +-pi flips every step: it shivers)
            turn = math.copysign(1.0, angle)
            if self._turn and abs(angle) > math.pi - ROTATE_KEEP_SIDE_RAD:
                turn = self._turn
            self._turn = turn
            return Command(0.0, turn * min(ROTATE_SPEED_RADPS, p.max_w), rotating=True)
        self._turn = 0.0
        l2 = lx * lx + ly * ly
        curvature = 2.0 * ly / l2 if l2 > 1e-9 else 0.0
        v = self._regulate(p.max_v, curvature, dist_goal, pose, costmap)
        w = v * curvature
        if abs(w) > p.max_w:  # keep the arc, slow down
            v *= p.max_w / abs(w)
            w = math.copysign(p.max_w, w)
        v = max(0.0, v)  # never reverse
        if costmap is not None and self._collides(pose, v, w, costmap, math.sqrt(l2)):
            return Command(0.0, 0.0, blocked=True)
        return Command(v, w)

    def _align(self, th: float) -> Command:
        if self.goal_yaw is None:
            return Command(0.0, 0.0, arrived=True)
        err = wrap_angle(self.goal_yaw - th)
        if abs(err) <= self.params.yaw_tolerance_rad:
            return Command(0.0, 0.0, arrived=True)
        w = math.copysign(min(ROTATE_SPEED_RADPS, self.params.max_w, max(0.3, abs(err))), err)
        return Command(0.0, w, rotating=True)

    def _regulate(self, v: float, curvature: float, dist_goal: float, pose: tuple[float, float, float],
                  costmap: Costmap | None) -> float:
        if abs(curvature) > 1e-9 and 1.0 / abs(curvature) < REGULATED_MIN_RADIUS_M:
            v *= (1.0 / abs(curvature)) / REGULATED_MIN_RADIUS_M
        if costmap is not None:
            d = self._clearance(pose, costmap) - costmap.inscribed_m
            if d < COST_SCALING_DIST_M:
                v *= COST_SCALING_GAIN * max(d, 0.0) / COST_SCALING_DIST_M
        v = max(v, MIN_REGULATED_SPEED_MPS)
        if dist_goal < APPROACH_DIST_M:
            v = min(v, max(MIN_APPROACH_SPEED_MPS, self.params.max_v * dist_goal / APPROACH_DIST_M))
        if costmap is not None:
            v = min(v, self.params.max_v * costmap.speed_limit_at(pose[0], pose[1]))
        return v

    @staticmethod
    def _clearance(pose: tuple[float, float, float], costmap: Costmap) -> float:
        """The least distance (m) to an obstacle where the robot is and CLEARANCE_AHEAD_M ahead:
        the speed drops before a tight gap, not in it."""
        x, y, th = pose
        c, s = math.cos(th), math.sin(th)
        return min(costmap.distance_at(x + d * c, y + d * s) for d in CLEARANCE_AHEAD_M)

    def _collides(self, pose: tuple[float, float, float], v: float, w: float, costmap: Costmap,
                  carrot_m: float) -> bool:
        """Simulate the arc for COLLISION_HORIZON_S (at least MIN_COLLISION_CHECK_M, at most up to
        the carrot, as Nav2). A point in collision counts unless the robot is already that close
        to an obstacle and the arc takes it no closer (leaving a wall)."""
        if v <= 1e-6:
            return False
        x, y, th = pose
        here = costmap.distance_at(x, y)
        dt = COLLISION_STEP_M / v
        check_m = min(max(COLLISION_HORIZON_S * v, MIN_COLLISION_CHECK_M), max(carrot_m, COLLISION_STEP_M))
        n = max(1, int(check_m / COLLISION_STEP_M))
        pts = []
        for _ in range(n):
            th += w * dt
            x += v * math.cos(th) * dt
            y += v * math.sin(th) * dt
            pts.append((x, y))
        return _hits(np.array(pts), here, costmap)

    @staticmethod
    def _line_collides(pose: tuple[float, float, float], to: np.ndarray, costmap: Costmap) -> bool:
        """Whether driving straight from ``pose`` to ``to`` collides (as :meth:`_collides`)."""
        x, y, _ = pose
        length = math.hypot(to[0] - x, to[1] - y)
        n = max(1, math.ceil(length / COLLISION_STEP_M))
        t = np.arange(1, n + 1)[:, None] / n
        here = np.array([x, y])
        return _hits(here + t * (np.asarray(to[:2]) - here), costmap.distance_at(x, y), costmap)


def _hits(points: np.ndarray, here: float, costmap: Costmap) -> bool:
    """Whether (N, 2) points ahead of a robot whose clearance is ``here`` (m) collide: a point in
    collision counts unless the robot is already that close and gets no closer there."""
    hit = costmap.blocked(points)
    if not hit.any():
        return False
    closer = np.array([costmap.distance_at(px, py) < here - 1e-3 for px, py in points[hit]])
    return bool(closer.any() or here > costmap.inscribed_m)


ESCAPE_STEP_RAD = math.radians(15.0)  # headings tried when stepping away from an obstacle
ESCAPE_SAMPLE_M = 0.05  # spacing of the distance samples along a tried heading (m)
ESCAPE_MIN_GAIN_M = 0.05  # a heading must take the robot at least this much further away (m)
ESCAPE_TURN_PENALTY_M = 0.05  # per pi of turn away from the preferred heading (m)


def escape_heading(costmap: Costmap, pose: tuple[float, float, float], reach_m: float,
                   prefer: float | None = None) -> float | None:
    """The heading (map frame, rad) in which driving straight for ``reach_m`` takes the robot
    furthest from the nearest obstacle without ever bringing it closer; ``None`` when no
    heading gains ``ESCAPE_MIN_GAIN_M``. Ties go to the heading nearest ``prefer``.

    Used when the robot stands inside an obstacle's inscribed radius (the forward check then
    stops every arc that gets closer): a round robot can turn where it stands and leave."""
    x, y, _ = pose
    here = costmap.distance_at(x, y)
    steps = np.arange(1, round(reach_m / ESCAPE_SAMPLE_M) + 1) * ESCAPE_SAMPLE_M
    best, best_score = None, -math.inf
    for heading in np.arange(-math.pi, math.pi, ESCAPE_STEP_RAD):
        d = np.array([costmap.distance_at(x + s * math.cos(heading), y + s * math.sin(heading))
                      for s in steps])
        if (d < here - 1e-3).any() or d[-1] < here + ESCAPE_MIN_GAIN_M:
            continue
        turn = abs(wrap_angle(float(heading) - prefer)) if prefer is not None else 0.0
        score = float(d[-1]) - ESCAPE_TURN_PENALTY_M * turn / math.pi
        if score > best_score:
            best, best_score = float(heading), score
    return best

