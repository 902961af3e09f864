"""CARMEN log parsing: each line type, gzip, and clear errors on malformed lines."""

from __future__ import annotations

import gzip
import math
from pathlib import Path

import numpy as np
import pytest

from sage_robot.nav.slam.carmen import LogFormatError, read_log
from sage_robot.nav.slam.relations import read_relations

FLASER = "FLASER 5 1.00 2.00 3.00 4.00 81.91 0.5 0.25 0.1 0.6 0.3 0.2 1134864629.895182 b21 0.086295"
ODOM = "ODOM 1.5 -2.0 0.3 0.4 0.1 0.0 1134864630.000001 b21 0.1"
# type start fov res max_range accuracy remission_mode | n ranges | n_rem | laser pose | robot pose |
# tv rv fwd side turn_axis | ts host ts
ROBOTLASER = (
    "ROBOTLASER1 0 -1.5708 3.14159 0.0174533 30.0 0.01 0 "
    "3 1.0 2.0 3.0 0 "
    "1.1 2.0 0.5 1.0 2.0 0.5 "
    "0.2 0.0 0.5 0.3 1000000.0 1134864631.5 host 0.2"
)


def write(tmp_path: Path, *lines: str, name: str = "a.clf") -> Path:
    path = tmp_path / name
    path.write_text("\n".join(lines) + "\n")
    return path


def test_flaser_odom_and_params(tmp_path: Path) -> None:
    path = write(
        tmp_path,
        "# comment",
        "PARAM robot_front_laser_max 50 1.0 b21 1.0",
        "PARAM robot_frontlaser_offset 0.1 1.0 b21 1.0",
        FLASER,
        ODOM,
        "SYNC 1 2 3",
    )
    log = read_log(path)
    assert len(log.scans) == 1
    assert len(log.odoms) == 1
    scan = log.scans[0]
    assert scan.stamp == pytest.approx(1134864629.895182)
    np.testing.assert_allclose(scan.ranges, [1, 2, 3, 4, 81.91], rtol=1e-6)
    assert scan.odom == (0.6, 0.3, 0.2)  # the robot's odometry, not the laser pose
    assert scan.range_max == 50.0
    assert scan.laser_offset == (0.1, 0.0, 0.0)
    # 5 beams over 180°: -90°, -45°, 0°, 45°, 90° (odd counts include both ends)
    np.testing.assert_allclose(scan.angles, np.radians([-90, -45, 0, 45, 90]))
    odom = log.odoms[0]
    assert odom.pose == (1.5, -2.0, 0.3)
    assert odom.tv == 0.4
    assert odom.stamp == pytest.approx(1134864630.000001)
    assert scan.line == 4


def test_robotlaser1(tmp_path: Path) -> None:
    log = read_log(write(tmp_path, ROBOTLASER))
    scan = log.scans[0]
    np.testing.assert_allclose(scan.ranges, [1, 2, 3])
    assert scan.angle_min == pytest.approx(-1.5708)
    assert scan.angle_increment == pytest.approx(0.0174533)
    assert scan.range_max == 30.0
    assert scan.stamp == pytest.approx(1134864631.5)
    assert scan.odom == (1.0, 2.0, 0.5)
    # laser 0.1 m along x of the map, robot heading 0.5 rad: offset in the robot frame
    assert scan.laser_offset[0] == pytest.approx(0.1 * math.cos(0.5))
    assert scan.laser_offset[1] == pytest.approx(-0.1 * math.sin(0.5))
    assert scan.laser_offset[2] == pytest.approx(0.0)


def test_gzip_is_read_by_content(tmp_path: Path) -> None:
    path = tmp_path / "log.gz"
    with gzip.open(path, "wt") as f:
        f.write(FLASER + "\n" + ODOM + "\n")
    assert len(read_log(path).scans) == 1


@pytest.mark.parametrize(
    ("line", "expected"),
    [
        ("FLASER 5 1.0 2.0 3.0 4.0 5.0 0 0 0 0 0 0 1.0 b21", "found 15 fields"),
        ("FLASER x 1.0", "an integer number of range readings, not 'x'"),
        ("FLASER 2 1.0 abc 0 0 0 0 0 0 1.0 b21 1.0", "a number for the ranges, not 'abc'"),
        ("ODOM 1 2 3 4 5 6 7 host", "found 9 fields"),
        ("ODOM 1 2 zz 4 5 6 7 host 8", "not 'zz'"),
        ("ROBOTLASER1 0 -1.57 3.14 0.017 30 0.01 0 3 1 2 3 0 1 2", "3 ranges, 0 remissions"),
    ],
)
def test_malformed_lines_name_file_line_and_expectation(tmp_path: Path, line: str, expected: str) -> None:
    path = write(tmp_path, FLASER, line)
    with pytest.raises(LogFormatError) as err:
        read_log(path)
    msg = str(err.value)
    assert msg.startswith(f"{path}:2: {line.split()[0]}: expected")
    assert expected in msg


def test_missing_and_empty_logs(tmp_path: Path) -> None:
    with pytest.raises(LogFormatError, match="log file not found"):
        read_log(tmp_path / "nope.clf")
    with pytest.raises(LogFormatError, match="no FLASER or ROBOTLASER1"):
        read_log(write(tmp_path, ODOM))


def test_relations_file(tmp_path: Path) -> None:
    path = write(tmp_path, "1.0 2.0 0.3 0.01 0 0 0 0.2", "2.0 3.0 0.1 0 0 0 0 -0.1", name="r.relations")
    rels = read_relations(path)
    assert [(r.t1, r.t2, r.dx, r.dy, r.dtheta) for r in rels] == [
        (1.0, 2.0, 0.3, 0.01, 0.2),
        (2.0, 3.0, 0.1, 0.0, -0.1),
    ]
    bad = write(tmp_path, "1.0 2.0 0.3", name="bad.relations")
    with pytest.raises(LogFormatError, match=r"bad.relations:1: expected 8 numbers"):
        read_relations(bad)
