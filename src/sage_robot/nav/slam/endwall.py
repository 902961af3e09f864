"""The lidar's straight-ahead range as a ruler for the odometry's scale.

While the robot drives straight, the beams straight ahead (and behind) hit the same wall scan
after scan, and that range shrinks (grows) by exactly the distance driven. Fitting it against
the odometry's travel gives the odometry's scale without the scan matcher: the tracked pose
along a corridor, which the calibration's stretches compare with, carries the matcher's
travel bias (``docs/slam.md``, "The matcher's bias keyframe by keyframe") and drifts along
weakly pinned corridors; a range is the lidar's own measurement.

:class:`EndWallRuler` collects one straight stretch of the odometry (its heading within
``MAX_HEADING_CHANGE_RAD``, no step turning more than ``MAX_STEP_TURN_RAD``: a gyro's heading)
and, when it ends, fits each direction's range against the travel where the range changes like
the travel (one wall; a person or a door frame in the beam breaks it), over at least
``MIN_SPAN_M``. Returns farther than ``MAX_RANGE_M`` are left out: near the lidar's reach only
the returns the noise made short come back, and they would read the travel short.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from sage_robot.nav.slam.points import Pose, Scan

BEAM_HALF_WIDTH_RAD = math.radians(2.0)  # beams this close to straight ahead / behind
MIN_BEAMS = 2  # returns in that cone for a range (their median)
MAX_RANGE_M = 9.0  # farther returns are left out (a 12 m lidar: 3 sigma of 1 % noise short of it)
MAX_HEADING_CHANGE_RAD = 0.05  # a straight stretch keeps its heading within this...
MAX_STEP_TURN_RAD = 0.01  # ...and no step turns more than this
MIN_SCANS = 15  # a fit needs this many ranges on one wall...
MIN_SPAN_M = 3.0  # ...spread over this much travel
MAX_SCANS = 3000  # a stretch this long is fitted and started again (a robot standing still)
# a range belongs to the same wall when it is within this (m, + this fraction of the range, the
# lidar's noise) of the previous one moved by the travel
SAME_WALL_M = 0.1
SAME_WALL_FRACTION = 0.03
OUTLIER_SIGMAS = 3.0  # residuals beyond this many sigmas leave the fit (twice)


@dataclass(frozen=True)
class WallFit:
    scale: float  # true travel / odometry travel
    span_m: float  # odometry travel the fit spans


def straight_range(scan: Scan, direction_rad: float, max_range_m: float = MAX_RANGE_M) -> float:
    """Median range (m) of the returns within ``BEAM_HALF_WIDTH_RAD`` of ``direction_rad``
    (robot frame); nan when fewer than ``MIN_BEAMS``."""
    off = np.abs(np.remainder(scan.angles + scan.laser[2] - direction_rad + math.pi, 2 * math.pi) - math.pi)
    r = np.asarray(scan.ranges, dtype=np.float64)[off <= BEAM_HALF_WIDTH_RAD]
    r = r[np.isfinite(r) & (r > scan.range_min) & (r < min(scan.range_max, max_range_m))]
    return float(np.median(r)) if len(r) >= MIN_BEAMS else math.nan


def fit_wall(travel: np.ndarray, ranges: np.ndarray, sign: float) -> WallFit | None:
    """The slope of ``ranges`` (m, nan: none) against ``travel`` (m of odometry) over the
    longest run on one wall: ``sign`` -1 for a wall ahead (the range shrinks), +1 behind."""
    idx = np.nonzero(np.isfinite(ranges))[0]
    if len(idx) < MIN_SCANS:
        return None
    best: list[int] = []
    run = [int(idx[0])]
    for i in idx[1:]:
        j = run[-1]
        expected = ranges[j] + sign * (travel[i] - travel[j])
        if abs(ranges[i] - expected) < SAME_WALL_M + SAME_WALL_FRACTION * ranges[i]:
            run.append(int(i))
        else:
            best, run = max(best, run, key=len), [int(i)]
    best = max(best, run, key=len)
    x, y = travel[best], ranges[best]
    for _ in range(2):
        if len(x) < MIN_SCANS or float(np.ptp(x)) < MIN_SPAN_M:  # (standing still: no slope)
            return None
        slope, icpt = np.polyfit(x, y, 1)
        res = y - (slope * x + icpt)
        keep = np.abs(res) <= OUTLIER_SIGMAS * max(float(res.std()), 1e-3)
        x, y = x[keep], y[keep]
    if len(x) < MIN_SCANS or float(np.ptp(x)) < MIN_SPAN_M:
        return None
    slope, _ = np.polyfit(x, y, 1)
    return WallFit(float(sign * slope), float(np.ptp(x)))


@dataclass
class EndWallRuler:
    """Feed every scan with its raw odometry pose; :meth:`step` returns the fits of a straight
    stretch that just ended."""

    _heading: float | None = None
    _origin: tuple[float, float] = (0.0, 0.0)
    _last_heading: float = 0.0
    _travel: list[float] = field(default_factory=list)
    _ahead: list[float] = field(default_factory=list)
    _behind: list[float] = field(default_factory=list)

    def step(self, odom: Pose, scan: Scan) -> list[WallFit]:
        fits: list[WallFit] = []
        if self._heading is not None:
            turned = abs(math.remainder(odom[2] - self._heading, 2 * math.pi))
            step = abs(math.remainder(odom[2] - self._last_heading, 2 * math.pi))
            if turned > MAX_HEADING_CHANGE_RAD or step > MAX_STEP_TURN_RAD or len(self._travel) >= MAX_SCANS:
                fits = self.end()
        if self._heading is None:
            self._heading, self._origin = odom[2], (odom[0], odom[1])
        c, s = math.cos(self._heading), math.sin(self._heading)
        self._travel.append((odom[0] - self._origin[0]) * c + (odom[1] - self._origin[1]) * s)
        self._ahead.append(straight_range(scan, 0.0))
        self._behind.append(straight_range(scan, math.pi))
        self._last_heading = odom[2]
        return fits

    def end(self) -> list[WallFit]:
        """The current stretch ends (a turn, a gap in the odometry): its fits."""
        travel = np.array(self._travel)
        out = []
        if len(travel) >= MIN_SCANS:
            for ranges, sign in ((self._ahead, -1.0), (self._behind, 1.0)):
                fit = fit_wall(travel, np.array(ranges), sign)
                if fit is not None:
                    out.append(fit)
        self._heading = None
        self._travel, self._ahead, self._behind = [], [], []
        return out
