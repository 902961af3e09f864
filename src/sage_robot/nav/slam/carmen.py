"""CARMEN robot logs (``.clf`` / ``.log``, optionally gzipped): ``FLASER``, ``ROBOTLASER1``, ``ODOM``.

Formats (CARMEN ``logfile`` conventions):

- ``FLASER n r1..rn x y theta odom_x odom_y odom_theta ipc_timestamp host logger_timestamp``:
  a front laser of 180° field of view, beams evenly from -90° to +90° (``n`` odd: both ends
  included, e.g. 181 or 361 beams; ``n`` even: steps of 180°/n from -90°). ``x y theta`` is
  the laser's pose, ``odom_*`` the robot's odometry (m, rad).
- ``ROBOTLASER1 type start_angle fov resolution max_range accuracy remission_mode n r1..rn
  n_rem rem1..rem_nrem laser_x laser_y laser_th robot_x robot_y robot_th tv rv fwd_safety
  side_safety turn_axis ipc_timestamp host logger_timestamp``.
- ``ODOM x y theta tv rv accel ipc_timestamp host logger_timestamp``.

Other lines (``PARAM``, ``SYNC``, ``NEFF``, raw lasers, comments) are skipped, except the
parameter ``robot_frontlaser_offset`` (m, laser forward of the robot centre) and
``robot_front_laser_max`` (m). A malformed line raises :class:`LogFormatError` naming
``file:line`` and what was expected there.
"""

from __future__ import annotations

import gzip
import math
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from sage_robot.core.errors import SageError

Pose = tuple[float, float, float]

FLASER_FOV_RAD = math.pi  # CARMEN's front laser: 180°
DEFAULT_MAX_RANGE_M = 80.0  # readings at or beyond this are "no return" unless a PARAM says otherwise
FLASER_TAIL = 9  # x y theta odom_x odom_y odom_theta ipc_timestamp host logger_timestamp
ROBOTLASER_HEADER = 7  # type start_angle fov resolution max_range accuracy remission_mode
ROBOTLASER_TAIL = 14  # laser pose (3), robot pose (3), tv rv fwd side turn_axis, ts host ts
ODOM_FIELDS = 9  # x y theta tv rv accel ipc_timestamp host logger_timestamp


class LogFormatError(SageError):
    """A line of a robot log does not have the expected layout."""


@dataclass(frozen=True)
class LogScan:
    """One laser scan of a log. ``ranges`` in m (``>= range_max`` means no return);
    ``odom`` is the robot's odometry pose (x, y m; theta rad) when the scan was taken and
    ``laser_offset`` the laser's pose in the robot frame."""

    stamp: float  # ipc_timestamp, s
    ranges: np.ndarray
    angle_min: float  # rad, in the laser frame
    angle_increment: float  # rad
    range_max: float  # m
    odom: Pose
    laser_offset: Pose = (0.0, 0.0, 0.0)
    line: int = 0

    @property
    def angles(self) -> np.ndarray:
        return self.angle_min + self.angle_increment * np.arange(len(self.ranges))


@dataclass(frozen=True)
class LogOdom:
    stamp: float  # ipc_timestamp, s
    pose: Pose  # odometry (m, rad)
    tv: float  # m/s
    rv: float  # rad/s
    line: int = 0


@dataclass
class CarmenLog:
    path: Path
    scans: list[LogScan] = field(default_factory=list)
    odoms: list[LogOdom] = field(default_factory=list)
    params: dict[str, str] = field(default_factory=dict)

    @property
    def duration_s(self) -> float:
        """Time from the first to the last scan (s): the log's real duration."""
        return self.scans[-1].stamp - self.scans[0].stamp if len(self.scans) > 1 else 0.0


def open_text(path: Path) -> Iterator[str]:
    """Lines of a log, gunzipped when it is a gzip file (by content, not name)."""
    try:
        with path.open("rb") as probe:
            magic = probe.read(2)
    except FileNotFoundError:
        raise LogFormatError(f"{path}: log file not found") from None
    except IsADirectoryError:
        raise LogFormatError(f"{path}: is a directory, not a log file") from None
    opener = gzip.open if magic == b"\x1f\x8b" else open
    try:
        with opener(path, "rt", encoding="latin-1") as f:
            yield from f
    except (OSError, EOFError) as exc:
        raise LogFormatError(f"{path}: cannot read: {exc}") from None


class _Line:
    """A line split into fields, with error messages that name file:line."""

    def __init__(self, path: Path, number: int, fields: list[str]) -> None:
        self.where, self.fields = f"{path}:{number}", fields
        self.number = number

    def fail(self, expected: str) -> LogFormatError:
        got = " ".join(self.fields[:6]) + (" ..." if len(self.fields) > 6 else "")
        return LogFormatError(f"{self.where}: {self.fields[0]}: expected {expected}; got {got!r}")

    def floats(self, start: int, count: int, what: str) -> np.ndarray:
        chunk = self.fields[start : start + count]
        if len(chunk) != count:
            raise self.fail(f"{count} numbers for {what} at field {start + 1}")
        try:
            return np.array([float(v) for v in chunk], dtype=np.float64)
        except ValueError:
            bad = next(v for v in chunk if not _is_float(v))
            raise self.fail(f"a number for {what}, not {bad!r}") from None

    def count(self, index: int, what: str) -> int:
        if index >= len(self.fields):
            raise self.fail(f"the number of {what} at field {index + 1}")
        try:
            n = int(self.fields[index])
        except ValueError:
            raise self.fail(f"an integer number of {what}, not {self.fields[index]!r}") from None
        if n < 0:
            raise self.fail(f"a non-negative number of {what}")
        return n


def _is_float(v: str) -> bool:
    try:
        float(v)
    except ValueError:
        return False
    return True


def _pose(a: np.ndarray) -> Pose:
    return (float(a[0]), float(a[1]), float(a[2]))


def parse_flaser(line: _Line, max_range: float, laser_x: float) -> LogScan:
    n = line.count(1, "range readings")
    if len(line.fields) != 2 + n + FLASER_TAIL:
        raise line.fail(
            f"{n} ranges then x y theta odom_x odom_y odom_theta ipc_timestamp host "
            f"logger_timestamp ({2 + n + FLASER_TAIL} fields), found {len(line.fields)} fields"
        )
    ranges = line.floats(2, n, "the ranges")
    tail = line.floats(2 + n, 7, "the poses and timestamp")
    increment = FLASER_FOV_RAD / (n - 1) if n % 2 == 1 and n > 1 else FLASER_FOV_RAD / max(n, 1)
    return LogScan(
        stamp=float(tail[6]),
        ranges=ranges.astype(np.float32),
        angle_min=-FLASER_FOV_RAD / 2.0,
        angle_increment=increment,
        range_max=max_range,
        odom=_pose(tail[3:6]),
        laser_offset=(laser_x, 0.0, 0.0),
        line=line.number,
    )


def parse_robotlaser(line: _Line) -> LogScan:
    header = line.floats(
        1, ROBOTLASER_HEADER, "type start_angle fov resolution max_range accuracy remission_mode"
    )
    n = line.count(1 + ROBOTLASER_HEADER, "range readings")
    start = 2 + ROBOTLASER_HEADER
    ranges = line.floats(start, n, "the ranges")
    n_rem = line.count(start + n, "remission values")
    tail_at = start + n + 1 + n_rem
    if len(line.fields) != tail_at + ROBOTLASER_TAIL:
        raise line.fail(
            f"{n} ranges, {n_rem} remissions, then laser pose, robot pose, tv rv "
            f"forward_safety side_safety turn_axis ipc_timestamp host logger_timestamp "
            f"({tail_at + ROBOTLASER_TAIL} fields), found {len(line.fields)} fields"
        )
    tail = line.floats(tail_at, 11, "the poses and velocities")
    stamp = line.floats(tail_at + 11, 1, "the ipc_timestamp")
    laser, robot = _pose(tail[0:3]), _pose(tail[3:6])
    # The laser's pose in the robot frame: both poses are in the same (odometry) frame.
    c, s = math.cos(robot[2]), math.sin(robot[2])
    dx, dy = laser[0] - robot[0], laser[1] - robot[1]
    dth = math.atan2(math.sin(laser[2] - robot[2]), math.cos(laser[2] - robot[2]))
    offset = (c * dx + s * dy, -s * dx + c * dy, dth)
    return LogScan(
        stamp=float(stamp[0]),
        ranges=ranges.astype(np.float32),
        angle_min=float(header[1]),
        angle_increment=float(header[3]),
        range_max=float(header[4]),
        odom=robot,
        laser_offset=offset,
        line=line.number,
    )


def parse_odom(line: _Line) -> LogOdom:
    if len(line.fields) != 1 + ODOM_FIELDS:
        raise line.fail(
            f"x y theta tv rv accel ipc_timestamp host logger_timestamp "
            f"({1 + ODOM_FIELDS} fields), found {len(line.fields)} fields"
        )
    v = line.floats(1, 7, "x y theta tv rv accel ipc_timestamp")
    return LogOdom(float(v[6]), _pose(v[0:3]), float(v[3]), float(v[4]), line.number)


def read_log(path: str | Path, progress: bool = False) -> CarmenLog:
    """Parse a CARMEN log. ``progress`` shows a tqdm bar over the lines read."""
    path = Path(path)
    log = CarmenLog(path)
    lines: Iterator[str] = open_text(path)
    if progress:
        from tqdm import tqdm

        lines = tqdm(lines, desc=f"reading {path.name}", unit=" lines", leave=False)
    max_range = DEFAULT_MAX_RANGE_M
    laser_x = 0.0
    for number, text in enumerate(lines, start=1):
        fields = text.split()
        if not fields or fields[0].startswith("#"):
            continue
        kind = fields[0]
        line = _Line(path, number, fields)
        if kind == "FLASER":
            log.scans.append(parse_flaser(line, max_range, laser_x))
        elif kind == "ROBOTLASER1":
            log.scans.append(parse_robotlaser(line))
        elif kind == "ODOM":
            log.odoms.append(parse_odom(line))
        elif kind == "PARAM" and len(fields) >= 3:
            log.params[fields[1]] = fields[2]
            if fields[1] == "robot_frontlaser_offset":
                laser_x = float(line.floats(2, 1, "the laser offset")[0])
            elif fields[1] == "robot_front_laser_max":
                max_range = float(line.floats(2, 1, "the laser's maximum range")[0])
    if not log.scans:
        raise LogFormatError(f"{path}: no FLASER or ROBOTLASER1 lines: not a CARMEN laser log?")
    return log
