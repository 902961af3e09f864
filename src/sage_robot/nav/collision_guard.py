"""The last check on a velocity before it leaves the navigator (pure; numpy).

The planner and the controller see the world through the map and the robot's estimated pose; a
few centimetres of localization error in a tight place (the TurtleBot sandbox: pillars 1.45 m
apart, the robot creeping at 0.15 m/s) is enough for the body to touch a pillar or a person.
This check uses the live scan alone, in the robot's own frame, as Nav2's collision monitor
does: a command whose next control period would bring the body within ``MARGIN_M`` of a scan
return, and closer to it than now, has its forward speed cut to zero (turning in place stays
allowed: the body is a circle). Returns inside the body are the robot itself and are ignored.

Robot frame (base_link): x ahead, y left, metres; (v m/s, w rad/s).
"""

from __future__ import annotations

import math

import numpy as np

MARGIN_M = 0.02  # the body keeps at least this much from any scan return while moving toward it
# A lidar at knee height sees a person's legs (~0.07 m across, 0.11 m either side of the body's
# centre), not the 0.25 m body around them: 2 cm from the legs the body is already touched
# (the TurtleBot sandbox: the robot pressed on at 0.15 m/s against a stander, 126 contacts
# in a leg). Returns that look like a leg keep LEG_MARGIN_M: head-on between two legs the
# body's front lies 0.23 m beyond the legs' returns. A leg is a cluster of returns no wider
# than LEG_MAX_M that stands clear of what is beside it (neighbours LEG_CLEAR_M further on
# both sides): a door frame or a pillar, contiguous with a wall or wider, keeps MARGIN_M.
LEG_MARGIN_M = 0.24
LEG_MAX_M = 0.15
LEG_CLEAR_M = 0.1
CLUSTER_GAP_M = 0.06  # consecutive returns further apart than this are two clusters (m)
LOOKAHEAD_S = 0.1  # how far ahead the body is projected (two 20 Hz control periods)
SELF_FRACTION = 0.8  # returns nearer the centre than this share of the radius are the robot itself


def scan_points(angles: np.ndarray, ranges: np.ndarray, range_max: float,
                mount: tuple[float, float, float]) -> np.ndarray:
    """The scan's returns as (N, 2) points in the robot's frame (the lidar at ``mount``)."""
    ok = np.isfinite(ranges) & (ranges > 0.0) & (ranges < range_max)
    a = angles[ok] + mount[2]
    r = ranges[ok]
    return np.column_stack([mount[0] + r * np.cos(a), mount[1] + r * np.sin(a)])


def leg_like(points: np.ndarray) -> np.ndarray:
    """Which of the scan's returns (in beam order, as :func:`scan_points` gives them) belong
    to a leg: a cluster no wider than LEG_MAX_M whose neighbouring returns on both sides lie
    LEG_CLEAR_M further from the lidar (or are missing)."""
    n = len(points)
    out = np.zeros(n, dtype=bool)
    if n == 0:
        return out
    step = np.hypot(*np.diff(points, axis=0).T) if n > 1 else np.zeros(0)
    starts = np.concatenate([[0], np.flatnonzero(step > CLUSTER_GAP_M) + 1])
    ends = np.concatenate([starts[1:], [n]])
    rng = np.hypot(points[:, 0], points[:, 1])
    for k, (a, b) in enumerate(zip(starts, ends, strict=True)):
        if np.hypot(*(points[b - 1] - points[a])) > LEG_MAX_M:
            continue
        near = rng[a:b].min()
        before = rng[ends[k - 1] - 1] if k > 0 else np.inf
        after = rng[starts[k + 1]] if k + 1 < len(starts) else np.inf
        if before >= near + LEG_CLEAR_M and after >= near + LEG_CLEAR_M:
            out[a:b] = True
    return out


def guarded(v: float, w: float, points: np.ndarray, radius_m: float,
            lookahead_s: float = LOOKAHEAD_S, legs: np.ndarray | None = None) -> float:
    """The forward speed to send instead of ``v``: 0 when moving on would bring the body
    (``radius_m``) within MARGIN_M of a return it is getting closer to (LEG_MARGIN_M of one
    ``legs`` marks), else ``v``."""
    if v == 0.0 or len(points) == 0:
        return v
    d0 = np.hypot(points[:, 0], points[:, 1])
    outside = d0 >= SELF_FRACTION * radius_m
    if not outside.any():
        return v
    pts, d0 = points[outside], d0[outside]
    margin = np.where(legs[outside], LEG_MARGIN_M, MARGIN_M) if legs is not None else MARGIN_M
    th = w * lookahead_s
    if abs(w) < 1e-9:
        x, y = v * lookahead_s, 0.0
    else:
        x, y = v / w * math.sin(th), v / w * (1.0 - math.cos(th))
    d1 = np.hypot(pts[:, 0] - x, pts[:, 1] - y)
    if np.any((d1 < radius_m + margin) & (d1 < d0)):
        return 0.0
    return v
