"""Social behaviour rules (issue #20), pure: what the robot does about the people it tracks
(:mod:`sage_robot.nav.people_track`). Driving them is :mod:`sage_robot.nav.social_drive`.

- **Slow down near people** (:func:`people_speed_cap`): within ``SLOW_WITHIN_M`` of a
  tracked person the speed is capped at ``SLOW_MPS`` (on top of the controller's clearance
  regulation), within ``CREEP_WITHIN_M`` at ``CREEP_MPS``.
- **Keep right** (:func:`keep_right`): the planned path is moved to the right of the
  direction of travel by up to ``KEEP_RIGHT_MAX_M``, where the costmap leaves
  ``KEEP_RIGHT_CLEAR_M`` beyond the inscribed radius (so the controller does not slow for the
  wall), never nearer an obstacle than the path itself was; tapered to nothing at both ends.
- **Pull over** (:func:`crowd_ahead`, :func:`corridor_width`): ``PULL_OVER_PEOPLE`` or more
  people coming head-on within ``PULL_OVER_LOOK_M`` in a corridor narrower than
  ``PULL_OVER_CORRIDOR_M``.
- **Pass a group, never split it** (:func:`group_marks`): the segments between the members of
  a group are marked as obstacles for planning, so the path goes around the group.

Conventions: map frame, metres, radians, seconds; paths are (N, 2) arrays of (x, y).
"""

from __future__ import annotations

import math

import numpy as np

from sage_robot.nav.costmap import Costmap
from sage_robot.nav.people_track import Track, groups

SLOW_WITHIN_M = 1.5  # a tracked person this near caps the speed at SLOW_MPS (m)
SLOW_MPS = 0.3
CREEP_WITHIN_M = 0.8  # ... this near at CREEP_MPS (m)
CREEP_MPS = 0.15
KEEP_RIGHT_MAX_M = 0.5  # the path moves at most this far to the right (m)
KEEP_RIGHT_CLEAR_M = 0.6  # and only where this much is left beyond the inscribed radius (m)
KEEP_RIGHT_STEP_M = 0.05  # offsets tried in these steps (m)
KEEP_RIGHT_TANGENT_M = 0.5  # the direction of travel is taken over this much path either side (m)
KEEP_RIGHT_SMOOTH_M = 0.5  # the offset changes smoothly over this much path (m)
KEEP_RIGHT_TAPER_START_M = 0.5  # no offset at the path's start, full after this much (m)
KEEP_RIGHT_TAPER_END_M = 1.5  # and none at the goal, ramping down over this much (m)
PULL_OVER_PEOPLE = 2  # this many people coming head-on ...
PULL_OVER_LOOK_M = 5.0  # ... within this far ahead (m) ...
PULL_OVER_LANE_M = 1.5  # ... and this far either side of the robot's heading (m) ...
PULL_OVER_APPROACH_MPS = 0.2  # ... at this speed toward the robot, at least (m/s) ...
PULL_OVER_CORRIDOR_M = 2.5  # ... in a corridor narrower than this (m): pull over
PASSING_NEAR_M = 2.0  # while pulled over, people this near ahead have not passed yet (m)
CORRIDOR_PROBE_M = 3.0  # walls are looked for this far either side (m)
GROUP_MARK_STEP_M = 0.05  # group segments are marked every this much (m)


def nearest_person_m(pose: tuple[float, float, float], tracks: list[Track]) -> float:
    """Distance (m) from the robot to the nearest tracked person (inf: nobody)."""
    return min((math.hypot(k.x - pose[0], k.y - pose[1]) for k in tracks), default=math.inf)


def people_speed_cap(nearest_m: float) -> float:
    """The speed cap (m/s) for the nearest person at ``nearest_m`` (inf: no cap)."""
    if nearest_m <= CREEP_WITHIN_M:
        return CREEP_MPS
    if nearest_m <= SLOW_WITHIN_M:
        return SLOW_MPS
    return math.inf


def _distances(cm: Costmap, xy: np.ndarray) -> np.ndarray:
    """Distance (m) to the nearest lethal cell at (N, 2) points; 0 outside or in unknown space."""
    r, c = cm.geom.to_cell(xy[:, 0], xy[:, 1])
    ok = cm.geom.inside(r, c)
    out = np.zeros(len(xy), dtype=np.float64)
    out[ok] = cm.dist[r[ok], c[ok]]
    out[cm.blocked(xy)] = 0.0
    return out


def _right_normals(points: np.ndarray) -> np.ndarray:
    n = len(points)
    k = max(1, round(KEEP_RIGHT_TANGENT_M / max(_spacing(points), 1e-3)))
    idx = np.arange(n)
    t = points[np.minimum(idx + k, n - 1)] - points[np.maximum(idx - k, 0)]
    norm = np.hypot(t[:, 0], t[:, 1])
    norm[norm < 1e-9] = 1.0
    t = t / norm[:, None]
    return np.column_stack((t[:, 1], -t[:, 0]))


def _spacing(points: np.ndarray) -> float:
    return float(np.median(np.hypot(*np.diff(points, axis=0).T))) if len(points) > 1 else 0.0


def _window(values: np.ndarray, k: int, how: str) -> np.ndarray:
    padded = np.pad(values, k, mode="edge")
    stack = np.stack([padded[i:i + len(values)] for i in range(2 * k + 1)])
    out: np.ndarray = stack.min(axis=0) if how == "min" else stack.mean(axis=0)
    return out


def keep_right(points: np.ndarray, cm: Costmap, max_m: float = KEEP_RIGHT_MAX_M) -> np.ndarray:
    """``points`` moved to the right of the direction of travel where ``cm`` leaves room."""
    if max_m < 0 or not math.isfinite(max_m):
        raise ValueError(f"keep_right: max_m must be a finite distance >= 0, not {max_m}")
    if len(points) < 3 or max_m == 0:
        return points
    right = _right_normals(points)
    here = _distances(cm, points)
    need = np.minimum(here, cm.inscribed_m + KEEP_RIGHT_CLEAR_M)
    offset = np.zeros(len(points))
    going = np.ones(len(points), dtype=bool)  # every smaller offset was fine too
    for s in np.arange(1, round(max_m / KEEP_RIGHT_STEP_M) + 1) * KEEP_RIGHT_STEP_M:
        going &= _distances(cm, points + s * right) >= need - 1e-6
        offset[going] = s
    spacing = max(_spacing(points), 1e-3)
    k = max(1, round(KEEP_RIGHT_SMOOTH_M / spacing))
    offset = _window(_window(offset, k, "min"), k, "mean")  # never more than any point allows
    along = np.concatenate(([0.0], np.cumsum(np.hypot(*np.diff(points, axis=0).T))))
    taper = np.minimum.reduce([np.ones(len(points)), along / KEEP_RIGHT_TAPER_START_M,
                               (along[-1] - along) / KEEP_RIGHT_TAPER_END_M])
    moved = points + (offset * np.clip(taper, 0.0, 1.0))[:, None] * right
    bad = _distances(cm, moved) < need - 1e-6  # (cannot happen after the min; kept as a guard)
    moved[bad] = points[bad]
    out: np.ndarray = moved
    return out


def corridor_width(cm: Costmap, pose: tuple[float, float, float]) -> float:
    """Width (m) of the free space across the robot's heading at its position, between the map's
    walls (scan marks left out), looked for up to CORRIDOR_PROBE_M either side."""
    x, y, th = pose
    n = (-math.sin(th), math.cos(th))
    s = np.arange(0.0, CORRIDOR_PROBE_M + 1e-9, cm.geom.resolution / 2)
    width = 0.0
    for sign in (1.0, -1.0):
        pts = np.column_stack((x + sign * s * n[0], y + sign * s * n[1]))
        hit = np.flatnonzero(cm.wall_distance(pts) <= 0.0)
        width += float(s[hit[0]]) if len(hit) else CORRIDOR_PROBE_M
    return width


def crowd_ahead(pose: tuple[float, float, float], tracks: list[Track]) -> list[Track]:
    """The tracked people coming head-on: ahead within PULL_OVER_LOOK_M and PULL_OVER_LANE_M of
    the robot's heading, walking toward it at PULL_OVER_APPROACH_MPS or faster."""
    x, y, th = pose
    c, s = math.cos(th), math.sin(th)
    out = []
    for k in tracks:
        lx, ly = c * (k.x - x) + s * (k.y - y), -s * (k.x - x) + c * (k.y - y)
        toward = -(c * k.vx + s * k.vy)  # speed along the robot's heading, toward it
        if 0.0 < lx <= PULL_OVER_LOOK_M and abs(ly) <= PULL_OVER_LANE_M and toward >= PULL_OVER_APPROACH_MPS:
            out.append(k)
    return out


def still_coming(pose: tuple[float, float, float], tracks: list[Track]) -> list[Track]:
    """While pulled over: the people still to pass, coming head-on (:func:`crowd_ahead`) or in
    the lane ahead within PASSING_NEAR_M (slowed down, or waiting to see what the robot does)."""
    x, y, th = pose
    c, s = math.cos(th), math.sin(th)
    near = [k for k in tracks if 0.0 < c * (k.x - x) + s * (k.y - y) <= PASSING_NEAR_M
            and abs(-s * (k.x - x) + c * (k.y - y)) <= PULL_OVER_LANE_M]
    return near + [k for k in crowd_ahead(pose, tracks) if k not in near]


def should_pull_over(cm: Costmap, pose: tuple[float, float, float], tracks: list[Track]) -> bool:
    """PULL_OVER_PEOPLE or more people coming head-on in a corridor narrower than PULL_OVER_CORRIDOR_M."""
    return len(crowd_ahead(pose, tracks)) >= PULL_OVER_PEOPLE and \
        corridor_width(cm, pose) < PULL_OVER_CORRIDOR_M


def group_marks(cm: Costmap, tracks: list[Track]) -> np.ndarray:
    """Cells (bool grid of ``cm``) on the segments between the members of each group (tracks
    within GROUP_M, chained): marked as obstacles, the planner goes around the group."""
    out = np.zeros(cm.geom.shape, dtype=bool)
    for group in groups(tracks):
        xy = [(k.x, k.y) for k in group]
        for i in range(len(xy)):
            for j in range(i + 1, len(xy)):
                (ax, ay), (bx, by) = xy[i], xy[j]
                n = max(2, math.ceil(math.hypot(bx - ax, by - ay) / GROUP_MARK_STEP_M) + 1)
                t = np.linspace(0.0, 1.0, n)
                r, c = cm.geom.to_cell(ax + t * (bx - ax), ay + t * (by - ay))
                ok = cm.geom.inside(r, c)
                out[r[ok], c[ok]] = True
    return out
