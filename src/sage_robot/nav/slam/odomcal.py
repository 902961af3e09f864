"""Online wheel-odometry calibration: the scale and heading drift the scan matcher measures.

Along a long bare corridor the scans say nothing about the position along it, so SLAM can
only follow the odometry there: a wheel that reads 2 % long puts the robot 24 cm off after
12 m. The same odometry, compared with the scan matcher where the scans *do* pin the pose
down (a room, a junction, a door frame), shows its error: this class keeps, from such
stretches, the odometry's scale (matched distance / odometry distance) and its heading drift
per metre, both as decaying weighted means, and corrects odometry steps with them.

A stretch counts when both of its ends were matched with the information along the direction
of travel at least ``MIN_ISOTROPY`` of the strongest direction's (or ``MIN_ALONG_INFO``), and it
is at least ``BASELINE_M`` long (the matcher's centimetre noise then weighs little) and at
most ``MAX_STRETCH_M`` (a longer one crossed ground the scans did not pin down, where the
tracker followed the very odometry it is compared with). Poses (x, y m; theta rad).

Once the calibration has compared ``GATE_AFTER_M``, a stretch whose matched length disagrees
with the calibrated odometry by more than ``MAX_DISAGREEMENT_M`` is left out (the tracker slid
along a weakly pinned corridor). When the map moves under the tracker (an optimisation), the
open stretches move with it (:meth:`OdometryCalibration.moved`).

Another ruler's readings of the scale count as stretches too (:meth:`OdometryCalibration.add_ruler`:
the lidar's range to a wall straight ahead while driving straight, :mod:`endwall`), once the
stretches have compared ``GATE_AFTER_M`` and within ``MAX_RULER_DISAGREEMENT`` of their scale.

How well the scale is known: :attr:`OdometryCalibration.scale_error`, the standard error of
the stretches' and rulers' readings (SLAM trusts the wheels' travel once it is small).

The turns' scale too (the wheels' track width, a gyro's sensitivity: both read a turn a
percent or two off): the matched turn over the odometry's, from turns of at least
``TURN_BASELINE_RAD`` between two matched scans (a bare corridor pins the heading down even
where it says nothing about the travel), less the heading drift learnt above.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sage_robot.core.geometry import compose, relative

Pose = tuple[float, float, float]

BASELINE_M = 2.0  # a calibration stretch is at least this long (m of odometry)
# ...and at most this long: a longer one crossed ground the scans did not pin down (a bare
# corridor between two door frames), where the tracker followed the odometry it is compared
# with (on the bench's corridor drive such stretches read 0.3-1.1 % short against the truth)
MAX_STRETCH_M = 3.0
MAX_STRETCH_TURN_RAD = 0.3  # ...and turns less than this (a turn's own scale error stays out)
MIN_ISOTROPY = 0.25  # information along the travel / strongest direction, at both ends...
MIN_ALONG_INFO = 25.0  # ...or at least this along the travel (1/m² per unit of one scan: with a
# few hundred points the end is then known to about a centimetre)
# ...and its matched length within this of the calibrated odometry's: the odometry's own noise
# over 2-3 m is a centimetre or two, a tracker that slid along a weakly pinned corridor is off
# by 5-45 cm (corridor drive, against the truth)...
MAX_DISAGREEMENT_M = 0.05
GATE_AFTER_M = 20.0  # ...once this much has been compared (a first estimate can be 0.5-2 % off)
# another ruler's scale (add_ruler) this far from the one learnt is left out: the stretches'
# first 20 m are good to a percent, a beam that followed a walking person or another wall reads
# 5-50 % off
MAX_RULER_DISAGREEMENT = 0.02
MAX_OUTLIERS_IN_ROW = 4  # this many disagreeing stretches in a row: the odometry changed, start again
MEMORY_M = 200.0  # older stretches fade out over about this many metres
SCALE_LIMITS = (0.8, 1.2)  # a scale outside this is not believed
MAX_YAW_DRIFT_RAD_PER_M = 0.05
MIN_READINGS = 5.0  # the scale's standard error is estimated from at least this many readings
MIN_CALIBRATED_M = 4.0  # corrections apply once this much odometry has been compared
# The turn scale (matched turn / odometry turn): from turns of at least TURN_BASELINE_RAD
# between two matched scans (the scans pin the heading down as well in a bare corridor)
TURN_BASELINE_RAD = 1.0
TURN_MEMORY_RAD = 30.0  # older turns fade out over about this much turning
TURN_SCALE_LIMITS = (0.9, 1.1)
MIN_CALIBRATED_TURN_RAD = 3.0  # the turn scale applies once this much turning has been compared


@dataclass
class _Anchor:
    pose: Pose  # matched
    odom: Pose


class OdometryCalibration:
    def __init__(self) -> None:
        self.scale = 1.0
        self.yaw_per_m = 0.0
        self._sum_est = 0.0  # decaying sums of matched and odometry distances (m)
        self._sum_odom = 0.0
        self._sum_yaw = 0.0  # decaying sum of heading differences (rad)...
        self._sum_yaw_odom = 0.0  # ...over this much odometry (m; the stretches' only)
        self._anchor: _Anchor | None = None
        self.turn_scale = 1.0
        self._sum_turn_est = 0.0  # decaying sums of matched and odometry turns (rad)
        self._sum_turn_odom = 0.0
        self._turn_anchor: _Anchor | None = None
        self._turned = 0.0  # odometry turn since the turn anchor (rad, signed)
        self._last_odom: Pose | None = None
        self.outliers = 0  # stretches left out: matched and odometry lengths disagreed
        self.ruler_outliers = 0  # other rulers' readings left out (add_ruler)
        self._stretches_m = 0.0  # odometry the stretches compared since the start or a reset (m)
        # decaying sums over the scale's readings (stretches and rulers), weighed by their
        # odometry length w: sum w, w², w r, w r² of the readings' scale r
        self._moments = (0.0, 0.0, 0.0, 0.0)
        self._outliers_in_row = 0

    @property
    def calibrated(self) -> bool:
        return self._sum_odom >= MIN_CALIBRATED_M

    @property
    def scale_error(self) -> float:
        """The standard error of the scale learnt (a fraction; inf before ``MIN_READINGS``
        readings): the spread of the readings' scales over the square root of how many count
        (weighed by their length, the old ones fading out as in the scale itself)."""
        w, w2, wr, wr2 = self._moments
        if w <= 0 or w2 <= 0:
            return math.inf
        n = w * w / w2
        if n < MIN_READINGS:
            return math.inf
        mean = wr / w
        return math.sqrt(max(wr2 / w - mean * mean, 0.0) / n)

    @property
    def turn_calibrated(self) -> bool:
        return self._sum_turn_odom >= MIN_CALIBRATED_TURN_RAD

    def correct(self, step: Pose) -> Pose:
        """An odometry increment (robot frame) with the calibration applied."""
        turn = self.turn_scale * step[2] if self.turn_calibrated else step[2]
        if not self.calibrated:
            return (step[0], step[1], turn)
        dist = math.hypot(step[0], step[1])
        return (self.scale * step[0], self.scale * step[1], turn - self.yaw_per_m * dist)

    def observe(self, pose: Pose, odom: Pose, information: np.ndarray | None) -> None:
        """Feed one matched scan: its pose, the raw odometry pose and the match's information
        (None: not matched, which ends the current stretch)."""
        self._observe_turn(pose, odom, information is not None)
        if information is None:
            self._anchor = None
            return
        if not self._pinned(pose, information):
            return
        if self._anchor is None:
            self._anchor = _Anchor(pose, odom)
            return
        d_odom = relative(self._anchor.odom, odom)
        dist = math.hypot(d_odom[0], d_odom[1])
        if dist < BASELINE_M:
            return
        d_est = relative(self._anchor.pose, pose)
        self._anchor = _Anchor(pose, odom)
        if abs(d_odom[2]) > MAX_STRETCH_TURN_RAD or dist > MAX_STRETCH_M:
            return
        matched = math.hypot(d_est[0], d_est[1])
        if self._sum_odom >= GATE_AFTER_M and abs(matched - self.scale * dist) > MAX_DISAGREEMENT_M:
            self.outliers += 1  # the tracker jumped (a weak match slid along a corridor)...
            self._outliers_in_row += 1
            if self._outliers_in_row < MAX_OUTLIERS_IN_ROW:
                return
            # ...or the odometry changed (a tyre, a load): what was learnt no longer holds
            self._sum_est = self._sum_odom = self._sum_yaw = self._sum_yaw_odom = 0.0
            self._stretches_m = 0.0
            self._moments = (0.0, 0.0, 0.0, 0.0)
        self._outliers_in_row = 0
        self._stretches_m += dist
        self._add_length(matched, dist)
        keep = math.exp(-dist / MEMORY_M)
        self._sum_yaw = keep * self._sum_yaw + math.remainder(d_odom[2] - d_est[2], 2 * math.pi)
        self._sum_yaw_odom = keep * self._sum_yaw_odom + dist
        yaw = self._sum_yaw / self._sum_yaw_odom
        self.yaw_per_m = min(max(yaw, -MAX_YAW_DRIFT_RAD_PER_M), MAX_YAW_DRIFT_RAD_PER_M)

    def add_ruler(self, scale: float, span_m: float) -> bool:
        """Another ruler's reading of the odometry's scale (true travel / odometry travel) over
        ``span_m`` of odometry (:mod:`~sage_robot.nav.slam.endwall`); it counts as a stretch of
        that length. Taken only once the stretches alone have compared ``GATE_AFTER_M``, and
        within ``MAX_RULER_DISAGREEMENT`` of the scale learnt: a person walking ahead at a
        tenth of the robot's speed reads 10 % off, a beam that followed another wall more.
        True when taken."""
        if not SCALE_LIMITS[0] < scale < SCALE_LIMITS[1] or span_m <= 0:
            return False
        if self._stretches_m < GATE_AFTER_M:
            return False
        if abs(scale - self.scale) > MAX_RULER_DISAGREEMENT:
            self.ruler_outliers += 1
            return False
        self._add_length(scale * span_m, span_m)
        return True

    def _add_length(self, matched: float, dist: float) -> None:
        keep = math.exp(-dist / MEMORY_M)
        self._sum_est = keep * self._sum_est + matched
        self._sum_odom = keep * self._sum_odom + dist
        self._add_moments(keep, matched / dist, dist)
        scale = self._sum_est / self._sum_odom
        self.scale = min(max(scale, SCALE_LIMITS[0]), SCALE_LIMITS[1])

    def _add_moments(self, keep: float, r: float, w: float) -> None:
        """One more reading of the scale, ``r`` over ``w`` m; the older ones weigh ``keep``."""
        sw, sw2, swr, swr2 = self._moments
        self._moments = (keep * sw + w, keep**2 * sw2 + w * w, keep * swr + w * r, keep * swr2 + w * r * r)

    def moved(self, before: Pose, after: Pose) -> None:
        """The map moved under the tracker (an optimisation: a loop closed): the current pose
        went from ``before`` to ``after``. The open stretches' anchors, measured against the
        same local map as the current pose, move with it; else the next stretch would read the
        correction as travel (on the corridor drive 20-45 cm in a 2 m stretch at the junction)."""
        for anchor in (self._anchor, self._turn_anchor):
            if anchor is not None:
                anchor.pose = compose(after, relative(before, anchor.pose))

    def forget_anchors(self) -> None:
        """The odometry starts again (a resumed session): no stretch spans the gap."""
        self._anchor = self._turn_anchor = None
        self._turned, self._last_odom = 0.0, None

    def _observe_turn(self, pose: Pose, odom: Pose, matched: bool) -> None:
        """The turn scale: matched turn / odometry turn over turns between matched scans."""
        if self._last_odom is not None:
            self._turned += math.remainder(odom[2] - self._last_odom[2], 2 * math.pi)
        self._last_odom = odom
        if not matched:
            self._turn_anchor, self._turned = None, 0.0
            return
        if self._turn_anchor is None:
            self._turn_anchor, self._turned = _Anchor(pose, odom), 0.0
            return
        if abs(self._turned) < TURN_BASELINE_RAD:
            return
        d_odom = relative(self._turn_anchor.odom, odom)
        drift = self.yaw_per_m * math.hypot(d_odom[0], d_odom[1]) if self.calibrated else 0.0
        odom_turn = self._turned - drift
        # the matched turn is the one nearest the odometry's (it may pass a full turn)
        d_est = math.remainder(pose[2] - self._turn_anchor.pose[2], 2 * math.pi)
        est_turn = d_est + 2 * math.pi * round((odom_turn - d_est) / (2 * math.pi))
        self._turn_anchor, self._turned = _Anchor(pose, odom), 0.0
        keep = math.exp(-abs(odom_turn) / TURN_MEMORY_RAD)
        self._sum_turn_est = keep * self._sum_turn_est + est_turn * math.copysign(1.0, odom_turn)
        self._sum_turn_odom = keep * self._sum_turn_odom + abs(odom_turn)
        ratio = self._sum_turn_est / self._sum_turn_odom
        self.turn_scale = min(max(ratio, TURN_SCALE_LIMITS[0]), TURN_SCALE_LIMITS[1])

    def _pinned(self, pose: Pose, information: np.ndarray) -> bool:
        """Does the match pin the pose down along the direction of travel (map frame)? At the
        start of a stretch: along every direction."""
        info = information[:2, :2]
        vals = np.linalg.eigvalsh(info)
        if vals[-1] <= 0:
            return False
        need = min(MIN_ISOTROPY * vals[-1], MIN_ALONG_INFO)
        if self._anchor is None:
            return bool(vals[0] >= need)
        d = np.array([pose[0] - self._anchor.pose[0], pose[1] - self._anchor.pose[1]])
        norm = float(np.hypot(d[0], d[1]))
        if norm < 1e-6:
            return bool(vals[0] >= need)
        u = d / norm
        return bool(u @ info @ u >= need)
