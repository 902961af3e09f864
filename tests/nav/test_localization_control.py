"""AMCL, health score, EKF and Regulated Pure Pursuit on hand-drawn grids."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sage_robot.core.geometry import wrap_angle
from sage_robot.nav.amcl import ParticleFilter, kld_count, sample_odometry, scan_fit
from sage_robot.nav.controller import ControllerParams, PurePursuit, escape_heading
from sage_robot.nav.costmap import Costmap
from sage_robot.nav.ekf import YawRateEkf
from sage_robot.nav.planner import plan

from ..support.grids import FREE, WALL, blank, draw, fill
from .nav_raycast import RANGE_MAX_M, beam_angles, cast

# An L-shaped floor with a pillar and alcoves: no two places look the same to a lidar.
FLOOR = """
##############################
#............................#
#............................#
#....##..............#########
#....##..............#.......#
#....................#.......#
#..........###...............#
#..........###...............#
#............................#
#######......................#
#...........#######..........#
#...........#.....#..........#
#............................#
##############################
"""

SENSOR = (0.0, 0.0, 0.0)


@pytest.fixture(scope="module")
def grid():
    return draw(FLOOR, 0.05, scale=10)  # 0.5 m per character: 15 m x 7 m


def _scan(grid, pose) -> tuple[np.ndarray, np.ndarray]:
    ang = beam_angles(180)
    return ang, cast(grid, pose, ang)


def _drive(pose, v, w, dt):
    x, y, t = pose
    return (x + v * math.cos(t) * dt, y + v * math.sin(t) * dt, wrap_angle(t + w * dt))


def test_kld_count_grows_with_spread_and_is_clamped() -> None:
    assert kld_count(1, 500, 2000) == 500
    assert kld_count(20, 500, 2000) < kld_count(200, 500, 2000) <= 2000
    assert kld_count(10_000, 500, 2000) == 2000


def test_motion_model_follows_odometry_on_average() -> None:
    rng = np.random.default_rng(1)
    p = np.zeros((4000, 3))
    out = sample_odometry(p, (0.0, 0.0, 0.0), (1.0, 0.0, 0.5), rng)
    assert np.median(np.hypot(out[:, 0], out[:, 1])) == pytest.approx(1.0, abs=0.05)
    assert np.mean(out[:, 2]) == pytest.approx(0.5, abs=0.03)
    assert out[:, 0].std() > 0.01  # it is noisy


def test_tracking_stays_within_a_few_cm(grid) -> None:
    rng = np.random.default_rng(7)
    pf = ParticleFilter(grid, rng, 500, 2000, SENSOR, beams=60)
    truth = (2.0, 1.5, 0.0)
    pf.set_pose(2.1, 1.4, 0.05)
    odom = (0.0, 0.0, 0.0)
    errs = []
    for k in range(80):
        w = 0.3 if 30 <= k < 45 else 0.0
        truth = _drive(truth, 0.5, w, 0.2)
        odom = _drive(odom, 0.5 * 1.02, w, 0.2)  # 2 % wheel error
        pf.update(odom, *_scan(grid, truth), RANGE_MAX_M)
        x, y, _ = pf.pose_at(odom)
        errs.append(math.hypot(x - truth[0], y - truth[1]))
    assert pf.updates > 20
    assert max(errs[-40:]) < 0.1
    assert 500 <= pf.count <= 2000


def test_global_localization_converges_once_the_robot_moves(grid) -> None:
    rng = np.random.default_rng(3)
    pf = ParticleFilter(grid, rng, 500, 2000, SENSOR)
    truth = (11.0, 2.0, math.pi / 2)
    pf.global_localization((*_scan(grid, truth), RANGE_MAX_M))
    odom = (0.0, 0.0, 0.0)
    for _ in range(25):
        truth = _drive(truth, 0.4, 0.0, 0.25)
        odom = _drive(odom, 0.4, 0.0, 0.25)
        pf.update(odom, *_scan(grid, truth), RANGE_MAX_M, force=True)
    e = pf.estimate()
    assert math.hypot(e.x - truth[0], e.y - truth[1]) < 0.3
    assert abs(wrap_angle(e.theta - truth[2])) < 0.15


def test_health_score_tells_lost_from_crowded(grid) -> None:
    pf = ParticleFilter(grid, np.random.default_rng(0), 500, 2000, SENSOR)
    pose = (3.0, 3.0, 0.3)
    ang = beam_angles(180)
    clean = cast(grid, pose, ang)
    crowd = cast(grid, pose, ang, people=[(4.0, 3.0, 0.25), (3.0, 4.2, 0.25), (2.0, 2.4, 0.25)])
    right = scan_fit(pf.field, pose, SENSOR, ang, clean, RANGE_MAX_M, 0.15)
    among_people = scan_fit(pf.field, pose, SENSOR, ang, crowd, RANGE_MAX_M, 0.15)
    wrong = scan_fit(pf.field, (9.0, 5.0, 2.0), SENSOR, ang, clean, RANGE_MAX_M, 0.15)
    assert right > 0.9
    assert among_people > 0.6
    assert wrong < 0.4


def test_a_crowd_round_the_robot_is_not_a_wrong_pose(grid) -> None:
    """Eight people round the robot hide most of the walls (willow-2010's hall: a few far walls,
    most returns from people and boxes, and the old score, 0.33, called a robot lost that was
    2 cm from the truth). Returns that end on free floor, 0.5 m or more from every mapped wall,
    with no wall before them, are not judged; one that passes through a wall is: a wrong pose
    still scores low."""
    pf = ParticleFilter(grid, np.random.default_rng(0), 500, 2000, SENSOR)
    pose = (3.0, 3.0, 0.3)
    ang = beam_angles(360)
    ring = [(pose[0] + 0.9 * math.cos(k * math.pi / 4), pose[1] + 0.9 * math.sin(k * math.pi / 4), 0.25)
            for k in range(8)]
    crowd = cast(grid, pose, ang, people=ring)
    walls = np.isfinite(crowd) & (crowd > 1.0)
    assert walls.mean() < 0.4  # most of the scan is people
    assert scan_fit(pf.field, pose, SENSOR, ang, crowd, RANGE_MAX_M, 0.15) > 0.8  # every return: 0.54
    for wrong in ((9.0, 5.0, 2.0), (3.0, 3.0, 1.2), (3.6, 3.3, 0.3)):
        assert scan_fit(pf.field, wrong, SENSOR, ang, cast(grid, pose, ang), RANGE_MAX_M, 0.15) < 0.6, wrong
    hall = (12.3, 2.5, 0.0)  # 2 m from every wall, walled in by sixteen people: nothing to judge
    ring = [(hall[0] + 0.8 * math.cos(k * math.pi / 8), hall[1] + 0.8 * math.sin(k * math.pi / 8), 0.25)
            for k in range(16)]
    walled_in = cast(grid, hall, ang, people=ring)
    assert np.isfinite(walled_in).all()
    assert math.isnan(scan_fit(pf.field, hall, SENSOR, ang, walled_in, RANGE_MAX_M, 0.15))


def test_ekf_trusts_the_gyro_for_heading() -> None:
    ekf = YawRateEkf()
    t = 0.0
    for _ in range(200):  # 4 s: wheels claim 0.3 rad/s, gyro says 0.2 rad/s
        t += 0.02
        ekf.odom(t, 0.5, 0.3)
        ekf.imu(t, 0.2)
    assert ekf.pose[2] == pytest.approx(0.2 * 4.0, abs=0.08)
    assert math.hypot(*ekf.pose[:2]) == pytest.approx(2.0, rel=0.1)


def _follow(grid, start, goal_xy, goal_yaw, steps=1500, costmap=None):
    cm = costmap or Costmap.from_grid(grid, 0.25, 0.55, 3.0)
    p = plan(cm, start[:2], goal_xy)
    ctl = PurePursuit(p.points, ControllerParams(), goal_yaw)
    pose, cmds = start, []
    for _ in range(steps):
        c = ctl.step(pose, cm)
        cmds.append(c)
        if c.arrived or c.blocked:
            break
        pose = _drive(pose, c.v, c.w, 0.05)
    return pose, cmds, cm


def test_pure_pursuit_reaches_goal_never_reverses(grid) -> None:
    pose, cmds, _cm = _follow(grid, (1.0, 6.0, 0.0), (13.0, 1.5), -math.pi / 2)
    assert cmds[-1].arrived
    assert math.hypot(pose[0] - 13.0, pose[1] - 1.5) <= 0.25
    assert abs(wrap_angle(pose[2] + math.pi / 2)) <= 0.25
    assert all(c.v >= 0.0 for c in cmds)
    assert max(c.v for c in cmds) <= 0.8 + 1e-9
    assert all(abs(c.w) <= 1.0 + 1e-9 for c in cmds)


@pytest.mark.parametrize("width_m", [0.6, 0.65, 0.8])
def test_a_corridor_a_little_wider_than_the_robot_is_followed_round_its_bend(width_m) -> None:
    # An L-shaped corridor 0.6 m wide (the robot is 0.5 m; the TurtleBot sandbox has such gaps
    # between its pillars and walls, issue #20). Even the short carrot's arc cut the inside of
    # the bend, and the controller said "blocked" at 0.6 and 0.65 m; it now takes the nearest
    # carrots, turning in place toward them, and drives round without touching a wall.
    g = blank(80, 80, 0.05)
    fill(g, 0.0, 0.0, 4.0, 4.0, WALL)
    fill(g, 0.5, 1.0, 2.0 + width_m, 1.0 + width_m, FREE)
    fill(g, 2.0, 1.0, 2.0 + width_m, 3.5, FREE)
    cm = Costmap.from_grid(g, 0.25, 0.55, 3.0)
    start, goal = (0.8, 1.0 + width_m / 2, 0.0), (2.0 + width_m / 2, 3.2)
    ctl = PurePursuit(plan(cm, start[:2], goal).points, ControllerParams(), None)
    pose, cmds, least = start, [], math.inf
    for _ in range(3000):
        cmds.append(ctl.step(pose, cm))
        if cmds[-1].arrived or cmds[-1].blocked:
            break
        pose = _drive(pose, cmds[-1].v, cmds[-1].w, 0.05)
        least = min(least, float(cm.wall_distance(np.array([pose[:2]]))[0]))
    assert cmds[-1].arrived, pose
    assert math.hypot(pose[0] - goal[0], pose[1] - goal[1]) <= 0.25
    assert least >= 0.25 - 0.025, least  # the body (0.25 m) never overlaps a wall cell (edge distance)
    assert all(c.v >= 0.0 for c in cmds)


def test_rotates_in_place_when_facing_away(grid) -> None:
    _, cmds, _ = _follow(grid, (3.0, 6.0, math.pi), (8.0, 6.0), None, steps=5)
    assert cmds[0].rotating
    assert cmds[0].v == 0.0
    assert cmds[0].w != 0.0


def test_forward_collision_check_stops_before_a_person(grid) -> None:
    cm = Costmap.from_grid(grid, 0.25, 0.55, 3.0)
    p = plan(cm, (1.0, 6.0), (9.0, 6.0))
    ang = beam_angles(180)
    cm.update_scan((2.0, 6.0, 0.0), ang, cast(grid, (2.0, 6.0, 0.0), ang, [(2.9, 6.0, 0.25)]), RANGE_MAX_M)
    ctl = PurePursuit(p.points, ControllerParams(), None)
    c = ctl.step((2.0, 6.0, 0.0), cm)
    assert c.blocked
    assert c.v == 0.0
    assert c.w == 0.0


def test_speed_zone_limits_speed(grid) -> None:
    cm = Costmap.from_grid(grid, 0.25, 0.55, 3.0)
    cm.speed[:] = 0.25
    _, cmds, _ = _follow(grid, (1.0, 6.0, 0.0), (9.0, 6.0), None, costmap=cm)
    assert max(c.v for c in cmds) <= 0.2 + 1e-9


def test_escape_heading_leads_away_from_a_wall_the_robot_is_too_close_to(grid) -> None:
    cm = Costmap.from_grid(grid, 0.25, 0.55, 3.0)
    pose = (5.0, 0.7, 0.0)  # 0.2 m from the bottom wall: inside the 0.25 m inscribed radius
    assert cm.distance_at(5.0, 0.7) < cm.inscribed_m
    heading = escape_heading(cm, pose, 0.5, prefer=0.0)
    assert heading is not None
    assert 0.0 < heading < math.pi  # away from the wall (+y)
    dist = [cm.distance_at(5.0 + s * math.cos(heading), 0.7 + s * math.sin(heading)) for s in (0.1, 0.3, 0.5)]
    assert dist == sorted(dist)
    assert dist[-1] > cm.inscribed_m
    # of the headings that leave, the one nearer the preferred direction wins
    left = escape_heading(cm, pose, 0.5, prefer=math.pi)
    assert left is not None
    assert left > heading

