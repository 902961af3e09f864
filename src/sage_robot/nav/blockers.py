"""What the scan shows standing where the robot wants to be (pure; numpy + scipy).

Used by the navigator's recovery ladder to tell the truth about why it stops: it settles short
of a goal only when something the lidar sees stands on the goal (issue #20: on a floor 1.45 m
wide every stop lay within reach of the goal, and the robot said "someone is standing at the
spot" with nobody there).

Map frame, metres; grids ``[row, col]`` as :class:`~sage_robot.nav.costmap.Costmap`.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

from sage_robot.nav.costmap import Costmap

GOAL_TAKEN_M = 0.5  # scan marks this near the goal stand on it: the robot does not fit there (m)
BLOB_SPAN_M = 1.5  # a blob on the goal is measured within this of it (m)
_JOIN = 2  # marks this many cells apart are one blob


def goal_taken(cm: Costmap, goal: tuple[float, float], within_m: float = GOAL_TAKEN_M) -> float | None:
    """The size (m, the larger side of its bounding box) of the largest blob of scan marks off
    the map's walls with a mark within ``within_m`` of ``goal``; None when there is none.
    Hits on a mapped wall (``Costmap.wall_zone``) are that wall, not something on the goal."""
    res = cm.geom.resolution
    k = math.ceil((within_m + BLOB_SPAN_M) / res)
    r, c = (int(v) for v in cm.geom.to_cell(goal[0], goal[1]))
    r0, c0 = max(r - k, 0), max(c - k, 0)
    sub = (cm.obstacles & ~cm.wall_zone)[r0:max(r + k + 1, 0), c0:max(c + k + 1, 0)]
    rows, cols = np.nonzero(sub)
    x, y = cm.geom.to_world(rows + r0, cols + c0)
    on = np.hypot(x - goal[0], y - goal[1]) <= within_m
    if not on.any():
        return None
    labels, _n = ndimage.label(ndimage.binary_dilation(sub, iterations=_JOIN), structure=np.ones((3, 3)))
    taken = set(np.unique(labels[rows[on], cols[on]]).tolist())
    spans = [max(sl[0].stop - sl[0].start, sl[1].stop - sl[1].start) - 2 * _JOIN
             for i, sl in enumerate(ndimage.find_objects(labels), start=1) if sl is not None and i in taken]
    return float(max(spans) * res)
