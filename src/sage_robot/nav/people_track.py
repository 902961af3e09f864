"""People from the lidar: scan returns that are not on the map, grouped into person-sized
blobs, tracked from scan to scan (issue #20, social behaviour).

Pure numpy/scipy, no clock of its own: every update carries the scan's stamp.

- :func:`scan_points`: a scan's returns in the map frame.
- :func:`person_blobs`: returns further than ``OFF_MAP_M`` from every mapped wall, joined
  when within ``JOIN_M`` (a person's two legs are one blob), kept when at most
  ``PERSON_MAX_M`` across and seen by at least ``MIN_POINTS`` beams; their centres.
- :class:`PeopleTracker`: nearest-neighbour association (greedy, closest pairs first, gate
  ``GATE_M`` plus how far a walker gets in the time since the track was seen), velocity by
  exponential smoothing of the displacement, tracks dropped after ``FORGET_S`` unseen.
- :func:`groups`: tracked people with at most ``GROUP_GAP_M`` between their bodies (centres
  within ``GROUP_M``, chained) form a group.

Conventions: map frame, metres, seconds; points are (N, 2) arrays of (x, y).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.sparse.csgraph import connected_components
from scipy.spatial.distance import cdist

from sage_robot.core.geometry import compose
from sage_robot.core.msgs import LaserScan
from sage_robot.nav.costmap import Costmap

OFF_MAP_M = 0.2  # a return this far from every mapped wall is not the map (m)
JOIN_M = 0.2  # returns this close are one blob (a person's legs are ~0.2 m apart) (m)
PERSON_MAX_M = 0.7  # a blob at most this wide could be a person (a body's arc, two legs) (m)
MIN_POINTS = 2  # a blob needs this many returns (one return is noise)
MAX_RANGE_M = 8.0  # returns further than this are not used (m)
GATE_M = 0.5  # a blob this near a track's predicted place may be that person (m)
WALK_MAX_MPS = 2.0  # nobody walks faster than this: widens the gate with the time unseen (m/s)
VELOCITY_SMOOTHING = 0.5  # weight of the newest velocity sample (0..1]
FORGET_S = 1.0  # a track unseen this long is dropped (s)
GROUP_GAP_M = 1.2  # people with at most this much room between them walk together (m) ...
BODY_RADIUS_M = 0.25  # ... a person's body around the tracked centre (m)
GROUP_M = GROUP_GAP_M + 2 * BODY_RADIUS_M  # ... so their centres are at most this far apart (m)


@dataclass
class Track:
    """One tracked person: where (m), how fast (m/s), seen since / last (s, the scans' stamps)."""

    id: int
    x: float
    y: float
    vx: float = 0.0
    vy: float = 0.0
    first_t: float = 0.0
    last_t: float = 0.0
    hits: int = 1

    @property
    def speed(self) -> float:
        return math.hypot(self.vx, self.vy)


def scan_points(pose: tuple[float, float, float], sensor: tuple[float, float, float],
                scan: LaserScan, max_range_m: float = MAX_RANGE_M) -> np.ndarray:
    """The finite returns of ``scan`` (shorter than ``max_range_m``) in the map frame, the robot
    at ``pose`` and the lidar at ``sensor`` on the robot. → (N, 2)."""
    sx, sy, st = compose(pose, sensor)
    r = np.asarray(scan.ranges, dtype=np.float64)
    a = np.asarray(scan.angles, dtype=np.float64) + st
    ok = np.isfinite(r) & (r > scan.range_min) & (r < min(max_range_m, scan.range_max))
    return np.column_stack((sx + r[ok] * np.cos(a[ok]), sy + r[ok] * np.sin(a[ok])))


def person_blobs(points: np.ndarray, cm: Costmap | None = None) -> np.ndarray:
    """Centres (M, 2) of the person-sized blobs among ``points`` off ``cm``'s map walls."""
    if len(points) and cm is not None:
        points = points[cm.wall_distance(points) > OFF_MAP_M]
    if len(points) < MIN_POINTS:
        return np.zeros((0, 2))
    d = cdist(points, points)
    n, labels = connected_components(d <= JOIN_M, directed=False)
    centres = []
    for i in range(n):
        blob = points[labels == i]
        if len(blob) < MIN_POINTS:
            continue
        if float(np.max(cdist(blob, blob))) > PERSON_MAX_M:
            continue
        centres.append(blob.mean(axis=0))
    return np.array(centres).reshape(-1, 2)


class PeopleTracker:
    """Nearest-neighbour tracks of person-sized blobs. ``update`` once per scan."""

    def __init__(self) -> None:
        self.tracks: list[Track] = []
        self._next_id = 1

    def update(self, t: float, centres: np.ndarray) -> list[Track]:
        """Associate this scan's blob centres (stamp ``t``) with the tracks; → the live tracks."""
        centres = np.asarray(centres, dtype=np.float64).reshape(-1, 2)
        if not np.all(np.isfinite(centres)):
            raise ValueError("people tracker: blob centres must be finite numbers")
        used: set[int] = set()
        if self.tracks and len(centres):
            pred = np.array([(k.x + k.vx * (t - k.last_t), k.y + k.vy * (t - k.last_t)) for k in self.tracks])
            gate = np.array([GATE_M + WALK_MAX_MPS * max(0.0, t - k.last_t) for k in self.tracks])
            d = cdist(pred, centres)
            matched: set[int] = set()
            for flat in np.argsort(d, axis=None, kind="stable"):
                i, j = divmod(int(flat), len(centres))
                if d[i, j] > gate[i]:
                    break
                if i in matched or j in used:
                    continue
                matched.add(i)
                used.add(j)
                self._correct(self.tracks[i], t, centres[j])
        for j, (x, y) in enumerate(centres):
            if j not in used:
                self.tracks.append(Track(self._next_id, float(x), float(y), first_t=t, last_t=t))
                self._next_id += 1
        self.tracks = [k for k in self.tracks if t - k.last_t <= FORGET_S]
        return list(self.tracks)

    @staticmethod
    def _correct(k: Track, t: float, xy: np.ndarray) -> None:
        dt = t - k.last_t
        if dt > 1e-6:
            a = VELOCITY_SMOOTHING if k.hits > 1 else 1.0
            k.vx = (1 - a) * k.vx + a * (float(xy[0]) - k.x) / dt
            k.vy = (1 - a) * k.vy + a * (float(xy[1]) - k.y) / dt
        k.x, k.y, k.last_t = float(xy[0]), float(xy[1]), t
        k.hits += 1

    def clear(self) -> None:
        self.tracks = []


def groups(tracks: list[Track], within_m: float = GROUP_M) -> list[list[Track]]:
    """The tracks that walk together: chained by ``within_m``; groups of two or more only."""
    if len(tracks) < 2:
        return []
    xy = np.array([(k.x, k.y) for k in tracks])
    n, labels = connected_components(cdist(xy, xy) <= within_m, directed=False)
    out = [[k for k, lab in zip(tracks, labels, strict=True) if lab == i] for i in range(n)]
    return [g for g in out if len(g) >= 2]
