"""Social behaviour (issue #20), the pure parts: the people tracker, the speed cap, keeping
right, pulling over, groups. Synthetic scans from the test lidar; no clock."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sage_robot.core.msgs import LaserScan
from sage_robot.nav.costmap import Costmap
from sage_robot.nav.people_track import PeopleTracker, Track, groups, person_blobs, scan_points
from sage_robot.nav.planner import plan
from sage_robot.nav.social import (
    KEEP_RIGHT_MAX_M,
    SLOW_MPS,
    corridor_width,
    crowd_ahead,
    group_marks,
    keep_right,
    people_speed_cap,
    should_pull_over,
)
from sage_robot.nav.social_drive import Social

from ..support.grids import draw, room
from .nav_raycast import RANGE_MAX_M, RANGE_MIN_M, beam_angles, cast

RES = 0.05
INSCRIBED_M, INFLATION_M, SCALING = 0.25, 0.55, 3.0
# A 3 m wide corridor (interior y 0.5..3.5), 14 m long; 0.5 m per character.
CORRIDOR_3M = """
##############################
#............................#
#............................#
#............................#
#............................#
#............................#
#............................#
##############################
"""
CENTRE_Y = 2.0
PERSON_R = 0.25


def _costmap(grid) -> Costmap:
    return Costmap.from_grid(grid, INSCRIBED_M, INFLATION_M, SCALING)


def _scan(grid, pose, people) -> LaserScan:
    angles = beam_angles()
    r = cast(grid, pose, angles, [(x, y, PERSON_R) for x, y in people])
    return LaserScan(0.0, "laser", -math.pi, 2 * math.pi / len(angles), RANGE_MIN_M, RANGE_MAX_M, r)


def _blobs(grid, cm, pose, people) -> np.ndarray:
    return person_blobs(scan_points(pose, (0.0, 0.0, 0.0), _scan(grid, pose, people)), cm)


def test_people_are_found_off_the_map_and_walls_are_not() -> None:
    grid = room(8.0, 6.0, RES)
    cm = _costmap(grid)
    people = [(3.0, 2.0), (5.0, 4.0)]
    centres = _blobs(grid, cm, (1.0, 1.0, 0.0), people)
    assert len(centres) == 2
    for px, py in people:  # the lidar sees the near arc: the centre is a little short of the body's
        assert min(math.hypot(cx - px, cy - py) for cx, cy in centres) < PERSON_R


def test_a_blob_wider_than_a_person_is_not_one() -> None:
    grid = room(8.0, 6.0, RES)
    cm = _costmap(grid)
    wall = np.column_stack((np.full(30, 4.0), np.linspace(2.0, 3.5, 30)))  # 1.5 m of unmapped wall
    assert len(person_blobs(wall, cm)) == 0
    with pytest.raises(ValueError, match="finite"):
        PeopleTracker().update(0.0, np.array([[math.nan, 1.0]]))


def test_tracks_keep_their_ids_and_learn_the_velocity() -> None:
    grid = room(10.0, 6.0, RES)
    cm = _costmap(grid)
    tracker = PeopleTracker()
    walkers = [np.array([2.0, 2.0]), np.array([8.0, 4.0])]
    velocity = [np.array([1.0, 0.0]), np.array([-0.5, 0.2])]
    ids = None
    for i in range(20):
        t = 0.1 * i
        where = [w + v * t for w, v in zip(walkers, velocity, strict=True)]
        tracks = tracker.update(t, _blobs(grid, cm, (5.0, 1.0, 0.0), [tuple(p) for p in where]))
        assert len(tracks) == 2
        if ids is None:
            ids = sorted(k.id for k in tracks)
        assert sorted(k.id for k in tracks) == ids
    for k in tracks:
        v = velocity[0] if k.x < 5.0 else velocity[1]
        assert math.hypot(k.vx - v[0], k.vy - v[1]) < 0.25, (k, v)
    assert tracker.update(3.5, np.zeros((0, 2))) == []  # unseen for FORGET_S: dropped


def test_speed_cap_by_the_nearest_person() -> None:
    assert people_speed_cap(math.inf) == math.inf
    assert people_speed_cap(1.4) == SLOW_MPS
    assert people_speed_cap(0.5) < SLOW_MPS


@pytest.mark.parametrize("heading", [0.0, math.pi])
def test_keep_right_moves_the_path_right_of_travel_in_a_3m_corridor(heading) -> None:
    cm = _costmap(draw(CORRIDOR_3M, RES, scale=10))
    a, b = (1.5, CENTRE_Y), (13.0, CENTRE_Y)
    start, goal = (a, b) if heading == 0.0 else (b, a)
    raw = plan(cm, start, goal).points
    kept = keep_right(raw, cm)
    right_y = -math.cos(heading)  # the right of travel, in y: east → south, west → north
    mid = kept[len(kept) // 4: 3 * len(kept) // 4]
    offset = (mid[:, 1] - CENTRE_Y) * right_y
    assert offset.mean() > 0.3
    assert offset.max() <= KEEP_RIGHT_MAX_M + 1e-6
    assert np.allclose(kept[-1], raw[-1])  # the goal stays where it was
    assert not cm.blocked(kept).any()


def test_keep_right_never_moves_a_path_nearer_an_obstacle_than_it_was() -> None:
    narrow = draw(CORRIDOR_3M, RES, scale=10)
    narrow.data[:round(1.2 / RES), :] = 100  # a 2.3 m corridor: the centre is 1.15 m from each wall
    cm = _costmap(narrow)
    raw = plan(cm, (1.5, 2.35), (13.0, 2.35)).points
    kept = keep_right(raw, cm)
    here = np.array([cm.distance_at(x, y) for x, y in raw])
    there = np.array([cm.distance_at(x, y) for x, y in kept])
    assert (there >= np.minimum(here, cm.inscribed_m + 0.6) - 1e-6).all()
    assert (raw[:, 1] - kept[:, 1]).max() > 0.2  # and yet it keeps right where there is room
    with pytest.raises(ValueError, match="max_m"):
        keep_right(raw, cm, max_m=-1.0)


def _track(x, y, vx, vy) -> Track:
    return Track(0, x, y, vx, vy)


def test_pull_over_for_a_crowd_head_on_in_a_narrow_corridor_only() -> None:
    narrow = draw(CORRIDOR_3M, RES, scale=10)
    narrow.data[:round(1.7 / RES), :] = 100  # interior y 1.7..3.5: 1.8 m wide
    wide = _costmap(draw(CORRIDOR_3M, RES, scale=10))
    cm = _costmap(narrow)
    pose = (3.0, 2.6, 0.0)
    assert corridor_width(cm, pose) == pytest.approx(1.8, abs=0.1)
    crowd = [_track(6.0, 3.0, -1.0, 0.0), _track(7.0, 2.8, -1.0, 0.0)]
    assert len(crowd_ahead(pose, crowd)) == 2
    assert should_pull_over(cm, pose, crowd)
    assert not should_pull_over(wide, (3.0, 2.0, 0.0), crowd)  # 3 m: room to pass
    assert not should_pull_over(cm, pose, crowd[:1])  # one person passes
    same_way = [_track(6.0, 3.0, 1.0, 0.0), _track(7.0, 2.8, 1.0, 0.0)]
    assert not should_pull_over(cm, pose, same_way)
    behind = [_track(1.0, 3.0, 1.0, 0.0), _track(0.8, 2.8, 1.0, 0.0)]
    assert not should_pull_over(cm, pose, behind)


def test_a_group_is_passed_around_not_split() -> None:
    # a 3.7 m corridor; two people side by side, 1.1 m between their bodies, 0.8 m from the walls
    grid = room(10.0, 3.8, RES)
    cm = _costmap(grid)
    cy = 1.9
    people = [(5.0, cy - 0.8), (5.0, cy + 0.8)]
    pose = (1.0, cy, 0.0)
    tracks = PeopleTracker().update(0.0, _blobs(grid, cm, pose, people))
    assert len(groups(tracks)) == 1
    scan = _scan(grid, pose, people)
    cm.update_scan(pose, scan.angles, scan.ranges, scan.range_max)
    between = plan(cm, pose[:2], (9.0, cy)).points  # without the group rule: between them
    at5 = between[np.argmin(np.abs(between[:, 0] - 5.0))]
    assert abs(at5[1] - cy) < 0.8

    class _Host:  # Social.plan needs only the costmap it is given
        pass

    social = Social(_Host(), None, 0.05)  # type: ignore[arg-type]
    around = social.plan(cm, pose[:2], (9.0, cy), tracks).points
    crossing = around[np.argmin(np.abs(around[:, 0] - 5.0))]
    assert abs(crossing[1] - cy) > 0.8, crossing  # beside the group, not through it
    assert group_marks(cm, tracks).any()
    assert not cm.blocked(around).any()
    alone = PeopleTracker().update(0.0, _blobs(grid, cm, pose, people[:1]))
    assert groups(alone) == []
