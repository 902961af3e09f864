"""The world: body kinematics and collisions, the lidar's blind spot, people, camera, seeds."""

from __future__ import annotations

import io
import math

import numpy as np
import pytest
from PIL import Image

from sage_robot.core.config import load_profile
from sage_robot.core.msgs.sim import LowObstacle
from sage_robot.core.paths import waypoints_yaml
from sage_robot.core.places import load_places
from sage_robot.sim.lidar import LidarSpec
from sage_robot.sim.people import PersonState
from sage_robot.sim.setup import build_world
from sage_robot.sim.spawn import STAND_OFF_PLACE_M
from sage_robot.sim.world import Collision, World

from ..support.grids import draw

DT = 0.01
TRACK_M = 0.381

# A 10 m x 4 m room of 0.5 m cells: the walls are one cell thick.
HALL = """
####################
#..................#
#..................#
#..................#
#..................#
#..................#
#..................#
####################
"""


def hall_world(**kw) -> World:
    grid = draw(HALL, 0.5)
    kw.setdefault("lidar", LidarSpec(noise_fraction=0.0, noise_floor_m=0.0, dropout_probability=0.0))
    return World(grid, kw.pop("start", (2.0, 2.0, 0.0)), **kw)


def drive_for(world: World, seconds: float, left: float, right: float) -> None:
    for _ in range(round(seconds / DT)):
        world.drive(DT, left, right, TRACK_M)
        world.step(DT)


def test_straight_and_turning_kinematics() -> None:
    w = hall_world()
    drive_for(w, 2.0, 0.5, 0.5)
    assert w.pose == pytest.approx((3.0, 2.0, 0.0), abs=1e-6)
    assert w.distance_m == pytest.approx(1.0)
    v, om = w.drive(DT, -0.1, 0.1, TRACK_M)
    assert (v, om) == pytest.approx((0.0, 0.2 / TRACK_M))


def test_a_wall_stops_the_body_and_counts_one_collision() -> None:
    w = hall_world()
    seen: list[Collision] = []
    w.on_collision.append(seen.append)
    drive_for(w, 20.0, 0.5, 0.5)  # the east wall's face is at x = 9.5
    assert w.x == pytest.approx(9.5 - 0.25, abs=0.05)
    assert w.collisions == 1
    assert seen[0].kind == "wall"
    v, _ = w.drive(DT, 0.5, 0.5, TRACK_M)
    assert v == 0.0  # still pushing: blocked, not a new collision
    assert w.collisions == 1
    drive_for(w, 1.0, -0.3, 0.3)  # turning in place works against a wall
    drive_for(w, 1.0, 0.3, 0.3)
    assert w.collisions == 1  # turned away (about 90°): drives off without hitting


def test_lidar_cannot_see_a_low_bench_but_the_body_hits_it() -> None:
    bench = LowObstacle("bench", 5.0, 2.0, 0.45, 1.6, 0.0, 0.45, "bench")
    w = hall_world(low_obstacles=(bench,))
    scan = w.scan(0.0)
    ahead = scan.ranges[len(scan.ranges) // 2]  # beam 180 of 360 looks straight ahead (0 rad)
    assert scan.angles[len(scan.ranges) // 2] == pytest.approx(0.0)
    assert ahead == pytest.approx(9.5 - 2.0 - 0.1466, abs=0.01)  # sees the far wall, not the bench
    drive_for(w, 10.0, 0.4, 0.4)
    assert w.collisions_by_kind == {"low_obstacle": 1}
    assert w.x == pytest.approx(5.0 - 0.225 - 0.25, abs=0.02)
    # The same box as tall as the scan plane is seen.
    tall = LowObstacle("cabinet", 5.0, 2.0, 0.45, 1.6, 0.0, 1.2, "cabinet")
    seen = hall_world(low_obstacles=(tall,)).scan(0.0).ranges[180]
    assert seen == pytest.approx(5.0 - 0.225 - 2.0 - 0.1466, abs=0.01)


def test_a_person_in_front_shows_up_in_the_scan_and_stops_the_body() -> None:
    empty = hall_world().scan(0.0).ranges
    person = PersonState(0, 4.0, 2.0, math.pi, "stander")
    w = hall_world(people=[person])
    r = w.scan(0.0).ranges
    front = slice(170, 191)  # +-10° around straight ahead
    assert np.nanmin(r[front]) < 4.0 - 2.0 - 0.1466 + 0.05
    assert np.nanmin(r[front]) > 1.5
    assert (r[front] < empty[front] - 1.0).sum() >= 2  # two legs, a few beams each
    drive_for(w, 10.0, 0.3, 0.3)
    assert w.collisions_by_kind == {"person": 1}
    assert w.x < 4.0 - 0.5 + 1e-6


def test_scan_message_matches_the_a1m8() -> None:
    w = hall_world(lidar=LidarSpec())
    scan = w.scan(1.5)
    assert scan.frame_id == "laser"
    assert len(scan.ranges) == 360
    assert scan.ranges.dtype == np.float32
    assert scan.range_min == 0.15
    assert scan.range_max == 12.0
    assert scan.scan_time == pytest.approx(0.1)
    finite = np.isfinite(scan.ranges)
    assert finite.mean() > 0.95  # a few dropouts at most (1 % of the beams on average)
    assert ((scan.ranges[finite] >= 0.15) & (scan.ranges[finite] <= 12.0)).all()


def test_lidar_noise_and_dropouts_are_seeded() -> None:
    spec = LidarSpec(dropout_probability=0.2)
    a = hall_world(lidar=spec, seed=5).scan(0.0).ranges
    b = hall_world(lidar=spec, seed=5).scan(0.0).ranges
    c = hall_world(lidar=spec, seed=6).scan(0.0).ranges
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)
    assert 0.1 < np.isinf(a).mean() < 0.3


def test_speaker_bearing_uses_the_seed_convention() -> None:
    left = hall_world(people=[PersonState(0, 2.0, 3.5, 0.0, "stander")])  # robot at (2, 2) facing east
    sp = left.speaker(0.0)
    assert sp.present
    assert sp.angle_deg == pytest.approx(90.0)
    assert sp.distance_m == pytest.approx(1.5)
    front = hall_world(people=[PersonState(0, 4.0, 2.0, 0.0, "stander")]).speaker(0.0)
    assert front.angle_deg == pytest.approx(180.0)
    far = hall_world(people=[PersonState(0, 8.0, 2.0, 0.0, "stander")]).speaker(0.0)
    assert not far.present


def run_world(seed: int, seconds: float) -> tuple[list[tuple[float, ...]], np.ndarray]:
    settings = load_profile(None, {"sim": {"seed": seed, "pedestrians": 6}})
    w = build_world(settings)
    poses = []
    for k in range(round(seconds / DT)):
        w.drive(DT, 0.3, 0.35, TRACK_M)
        w.step(DT)
        if k % 50 == 0:
            poses.append(w.pose + tuple(v for p in w.crowd.people for v in (p.x, p.y)))
    return poses, w.scan(w.t).ranges


def test_the_same_seed_gives_the_same_run() -> None:
    a, scan_a = run_world(11, 6.0)
    b, scan_b = run_world(11, 6.0)
    c, _ = run_world(12, 6.0)
    assert a == b
    assert np.array_equal(scan_a, scan_b)
    assert a != c


def test_people_walk_and_the_approacher_comes_to_the_robot() -> None:
    settings = load_profile(None, {"sim": {"seed": 3, "pedestrians": 6}})
    w = build_world(settings)
    kinds = [p.behaviour for p in w.crowd.people]
    assert kinds.count("walker") >= 1
    assert "stander" in kinds
    assert "approacher" in kinds
    assert "group" in kinds
    approacher = next(p for p in w.crowd.people if p.behaviour == "approacher")
    walker = next(p for p in w.crowd.people if p.behaviour == "walker")
    start = (walker.x, walker.y)
    for _ in range(round(60.0 / DT)):
        w.step(DT)
        for p in w.crowd.people:
            assert w.raycaster.clearance(p.x, p.y)[0] >= 0.2, "a person walked into a wall"
    assert math.hypot(walker.x - start[0], walker.y - start[1]) > 3.0
    assert math.hypot(approacher.x - w.x, approacher.y - w.y) < 1.5
    sp = w.speaker(w.t)
    assert sp.present
    assert sp.person_id == approacher.id
    assert sp.angle_deg == pytest.approx(180.0, abs=40.0)  # in front of the robot


def test_camera_gives_a_480x270_jpeg_that_changes_when_turning() -> None:
    w = build_world(load_profile(None, {"sim": {"pedestrians": 0}}))
    a = w.camera_msg(0.0)
    assert a.format == "jpeg"
    assert a.data[:2] == b"\xff\xd8"
    img = Image.open(io.BytesIO(a.data))
    assert img.size == (480, 270)
    assert img.mode == "RGB"
    drive_for(w, 1.0, -0.2, 0.2)  # turn left ~60°
    b = Image.open(io.BytesIO(w.camera_msg(1.0).data))
    diff = np.abs(np.asarray(img, dtype=np.int16) - np.asarray(b, dtype=np.int16)).mean()
    assert diff > 10.0


def test_a_start_inside_a_wall_is_refused() -> None:
    with pytest.raises(ValueError, match="overlaps wall"):
        hall_world(start=(0.6, 2.0, 0.0))


def test_the_approacher_does_not_chase_a_moving_robot() -> None:
    comer = PersonState(0, 6.0, 2.0, math.pi, "approacher", speed_mps=1.0, start_s=0.0, stay_s=30.0)
    w = hall_world(people=[comer], start=(1.0, 3.0, 0.0))
    drive_for(w, 1.0, 0.4, 0.4)  # the robot is moving: the visitor waits
    assert (comer.x, comer.y) == (6.0, 2.0)
    assert comer.behaviour == "approacher"
    drive_for(w, 4.0, 0.0, 0.0)  # stopped: they come and stand in front
    assert math.hypot(comer.x - (w.x + 1.0), comer.y - w.y) < 0.3
    assert comer.stay_until > w.t


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_groups_stand_clear_of_the_way_into_a_room(seed: int) -> None:
    w = build_world(load_profile(None, {"sim": {"seed": seed, "pedestrians": 6}}))
    lanes = w.crowd.lanes
    assert lanes is not None
    spurs = [(a, b) for a in range(len(lanes.nodes)) for b, half in lanes.adj[a] if half < 0.5 and a < b]
    assert len(spurs) == 15  # a door-to-place spur per room with a place
    for p in (p for p in w.crowd.people if p.behaviour == "group"):
        for a, b in spurs:
            pa, pb = lanes.nodes[a], lanes.nodes[b]
            f = np.clip(np.dot([p.x, p.y] - pa, pb - pa) / np.dot(pb - pa, pb - pa), 0.0, 1.0)
            gap = float(np.hypot(*([p.x, p.y] - (pa + f * (pb - pa)))))
            assert gap > 0.25 + 0.25 + 0.1, (p.x, p.y)  # the robot passes along the spur


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_standers_stand_by_a_wall(seed: int) -> None:
    w = build_world(load_profile(None, {"sim": {"seed": seed, "pedestrians": 6}}))
    for p in (p for p in w.crowd.people if p.behaviour == "stander"):
        assert w.raycaster.clearance_at(p.x, p.y) < 0.25 + 0.2, (p.x, p.y)


@pytest.mark.parametrize("seed", [0, 1, 2, 3, 4])
def test_people_who_stand_for_good_keep_off_the_places(seed: int) -> None:
    """A tour stop is where visitors come and go: the stander and a standing group keep
    STAND_OFF_PLACE_M from every place (the dock too), and everyone starts on the robot's floor."""
    settings = load_profile(None, {"sim": {"seed": seed, "pedestrians": 8}})
    w = build_world(settings)
    places = load_places(waypoints_yaml(settings))
    standing = [p for p in w.crowd.people if p.behaviour in ("stander", "group")]
    assert {p.behaviour for p in standing} == {"stander", "group"}
    for p in standing:
        near = min(math.hypot(p.x - q.pose.x, p.y - q.pose.y) for q in places)
        assert near >= STAND_OFF_PLACE_M, (p.behaviour, p.x, p.y)
    for p in w.crowd.people:
        assert w.raycaster.is_free(p.x, p.y), (p.behaviour, p.x, p.y)
