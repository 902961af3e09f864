"""The nav benchmark on any map: automatic places (``--places auto N``) and unmapped boxes that
leave a path the robot fits through between all places (``bench/nav_places.py``).

Real maps come from ``../shared/data/maps`` (the ``shared_data`` fixture skips the test when it
is absent); the synthetic ones always run. No benchmark is driven here.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

import sage_robot.bench.nav as bench_nav
import sage_robot.bench.nav_places as npl
from sage_robot.core.config import Settings
from sage_robot.core.mapio import FREE, OCCUPIED, UNKNOWN
from sage_robot.core.msgs import Event, OccupancyGrid, Pose2D
from sage_robot.core.msgs.nav import NavigateFeedback, NavState
from sage_robot.core.places import load_places
from sage_robot.nav.mapdata import load_map_data
from sage_robot.nav.planner import plan

RADIUS = Settings().robot.radius_m
REAL_MAPS = ["maps/tb3-sandbox/tb3_sandbox.yaml", "maps/willow-2010-02-18/willow-2010-02-18-0.10.yaml",
             "maps/willow-full/willow-full.yaml"]


def _space(path: Path) -> npl.FreeSpace:
    data = load_map_data(path)
    return npl.free_space(data.grid, data.keepout)


def _grid(data: np.ndarray, res: float = 0.1, origin: tuple[float, float] = (-7.3, 4.1)) -> OccupancyGrid:
    return OccupancyGrid(0.0, "map", res, Pose2D(*origin, 0.0), data.astype(np.int8))


def _two_rooms(corridor_w_m: float) -> OccupancyGrid:
    """Two 6 x 6 m rooms joined by a 4 m corridor ``corridor_w_m`` wide; unknown all round, a
    free island of 1 x 1 m inside the unknown, and speckles of unknown in the rooms."""
    d = np.full((100, 200), UNKNOWN, dtype=np.int16)
    d[10:80, 10:170] = OCCUPIED
    d[12:72, 12:72] = FREE  # room A (rows = y, cols = x; 0.1 m cells)
    d[12:72, 112:172 - 4] = FREE  # room B
    half = round(corridor_w_m / 0.2)
    d[42 - half:42 + half, 72:112] = FREE  # the corridor
    d[90:95, 185:195] = FREE  # a speck of free space out in the unknown
    d[30, 30] = d[50, 140] = UNKNOWN  # SLAM noise inside the rooms
    return _grid(d)


def _assert_good_places(space: npl.FreeSpace, pts: list[tuple[float, float]], n: int) -> None:
    assert len(pts) == n
    assert npl.min_separation(pts) >= npl.MIN_SEPARATION_M
    clear = space.clearance()
    reach = npl.reachable(space, RADIUS)
    for x, y in pts:
        r, c = space.to_cell(x, y)
        assert space.grid.data[r, c] == FREE, (x, y)  # never unknown or an obstacle
        assert not space.blocked[r, c]
        assert clear[r, c] >= RADIUS + npl.PASSAGE_MARGIN_M, (x, y)
        assert reach[r, c], (x, y)  # on the robot's own part of the map, not a speck
    assert npl.connected(space, RADIUS, pts)


# ------------------------------------------------------------------ synthetic maps (always run)
def test_auto_places_stay_off_unknown_speckles_and_islands() -> None:
    space = npl.free_space(_two_rooms(1.6))
    pts = npl.auto_places(space, 5, RADIUS, np.random.default_rng(3))
    _assert_good_places(space, pts, 5)
    assert all(x < -7.3 + 17.0 for x, _ in pts)  # none on the island out at x 11.5..12.5 m from the origin
    assert pts == npl.auto_places(space, 5, RADIUS, np.random.default_rng(3))


def test_auto_places_too_many_for_the_map_is_a_clear_error() -> None:
    from sage_robot.core.errors import ConfigError

    with pytest.raises(ConfigError, match="ask for fewer"):
        npl.auto_places(npl.free_space(_two_rooms(1.6)), 40, RADIUS, np.random.default_rng(0))


def test_a_room_behind_a_gap_the_robot_does_not_fit_is_not_reachable() -> None:
    space = npl.free_space(_two_rooms(0.5))  # 0.5 m: people pass, the 0.5 m robot does not
    reach = npl.reachable(space, RADIUS)
    a, b = space.to_cell(-7.3 + 4.0, 4.1 + 4.0), space.to_cell(-7.3 + 14.0, 4.1 + 4.0)
    assert reach[a] != reach[b]
    pts = npl.auto_places(space, 3, RADIUS, np.random.default_rng(1))
    assert npl.connected(space, RADIUS, pts)


def test_boxes_never_cut_the_only_corridor(monkeypatch: pytest.MonkeyPatch) -> None:
    # Let boxes go close to walls: in the 1.2 m corridor any box would leave gaps < the robot.
    monkeypatch.setattr(npl, "BOX_WALL_CLEARANCE_M", 0.45)
    space = npl.free_space(_two_rooms(1.2))
    pts = npl.auto_places(space, 4, RADIUS, np.random.default_rng(5))
    assert any(x < -7.3 + 7.2 for x, _ in pts)
    assert any(x > -7.3 + 11.2 for x, _ in pts)
    for seed in range(6):
        boxes, ok = npl.place_boxes(space, 8, pts, RADIUS, np.random.default_rng(seed))
        assert ok
        assert boxes
        blocked = space.blocked.copy()
        for b in boxes:
            assert not -7.3 + 7.6 < b.x < -7.3 + 10.8, b  # nothing inside the corridor
            cells = npl.box_cells(space, b)
            blocked[cells[:, 0], cells[:, 1]] = True
        assert npl.connected(space, RADIUS, pts, blocked)


def test_wait_watch_sums_waiting_and_counts_excuse_me() -> None:
    from sage_robot.core import topics

    class Clock:
        t = 0.0

        def now(self) -> float:
            return self.t

    clock = Clock()
    watch = bench_nav._WaitWatch(clock)
    for t, state in [(1.0, NavState.DRIVING), (2.0, NavState.WAITING_FOR_PEOPLE),
                     (3.0, NavState.WAITING_FOR_PEOPLE), (7.5, NavState.DRIVING),
                     (9.0, NavState.WAITING_FOR_PEOPLE)]:
        clock.t = t
        watch.see(topics.NAV_STATE, NavigateFeedback(state))
    watch.see(topics.EVENTS, Event(9.0, "navigator", "blocked_by_people", "excuse me, may I pass?", {}))
    watch.see(topics.EVENTS, Event(9.0, "navigator", "arrived", "arrived at the lab", {}))
    clock.t = 10.0
    assert watch.waited() == pytest.approx(5.5 + 1.0)
    assert watch.excuse_me == 1
    watch.reset()  # a new leg: the wait still running counts from now
    clock.t = 12.0
    assert watch.waited() == pytest.approx(2.0)
    assert watch.excuse_me == 0


# ------------------------------------------------------------------ real maps (shared data)
@pytest.mark.parametrize("rel", REAL_MAPS)
def test_auto_places_on_real_maps(rel: str, shared_data: Callable[[str], Path]) -> None:
    path = shared_data(rel)
    space = _space(path)
    pts = npl.auto_places(space, 6, RADIUS, np.random.default_rng(7))
    _assert_good_places(space, pts, 6)
    assert pts == npl.auto_places(space, 6, RADIUS, np.random.default_rng(7))  # a seed, one answer
    assert pts != npl.auto_places(space, 6, RADIUS, np.random.default_rng(8))
    if "willow" in rel:  # a building: places spread over it, not bunched in one room
        assert npl.min_separation(pts) > 10.0
    s = Settings()
    static = load_map_data(path).costmap(RADIUS, s.nav.inflation_radius_m, s.nav.cost_scaling_factor)
    if "tb3" not in rel:  # the planner finds a way from the dock to each (the sandbox: see docs)
        for p in pts[1:]:
            assert plan(static, pts[0], p).length_m >= math.dist(pts[0], p) - 0.2


def test_bench_writes_auto_waypoints_the_navigator_loads(shared_data: Callable[[str], Path],
                                                         tmp_path: Path) -> None:
    path = shared_data("maps/willow-2010-02-18/willow-2010-02-18-0.10.yaml")
    args = argparse.Namespace(map=str(path), places=["auto", "5"], seed=7)
    wp = bench_nav._auto_places(args, str(tmp_path))
    places = load_places(wp)
    assert places.names() == ["DOCKING_STATION", "PLACE_1", "PLACE_2", "PLACE_3", "PLACE_4"]
    again = load_places(bench_nav._auto_places(args, str(tmp_path)))
    assert [p.pose for p in again] == [p.pose for p in places]


def test_boxes_on_willow_keep_paths_between_all_places(shared_data: Callable[[str], Path]) -> None:
    space = _space(shared_data("maps/willow-2010-02-18/willow-2010-02-18-0.10.yaml"))
    pts = npl.auto_places(space, 6, RADIUS, np.random.default_rng(7))
    boxes, ok = npl.place_boxes(space, 5, pts, RADIUS, np.random.default_rng(7))
    assert ok
    assert len(boxes) == 5
    assert boxes == npl.place_boxes(space, 5, pts, RADIUS, np.random.default_rng(7))[0]
    blocked = space.blocked.copy()
    for b in boxes:
        assert min(math.hypot(b.x - x, b.y - y) for x, y in pts) > npl.BOX_PLACE_CLEARANCE_M
        cells = npl.box_cells(space, b)
        assert not space.blocked[cells[:, 0], cells[:, 1]].any()  # on free floor, not in a wall
        blocked[cells[:, 0], cells[:, 1]] = True
    assert npl.connected(space, RADIUS, pts, blocked)


def test_summary_counts_waiting_excuse_me_and_arrivals_short_of_the_goal() -> None:
    def leg(ok: bool, reason: str = "", waited: float = 0.0, excuse: int = 0) -> dict[str, object]:
        return {"from": "A", "to": "B", "ok": ok, "reason": reason, "collisions": 0, "time_s": 10.0,
                "length_m": 5.0, "shortest_m": 5.0, "loc_samples": 0, "loc_sq_m": 0.0, "loc_sq_deg": 0.0,
                "waited_s": waited, "excuse_me": excuse}

    out = bench_nav.summarize([
        leg(True, waited=2.5, excuse=1),
        leg(False, f"{bench_nav.SAID_ARRIVED} 2.1 m from the goal (stopped short)", 60.0, 2),
        leg(False, "the way is blocked"),
        {k: v for k, v in leg(True).items() if k not in ("waited_s", "excuse_me")},  # an older legs file
    ])
    assert out["time_waiting_s"] == 62.5
    assert out["excuse_me"] == 3
    assert out["arrived_short"] == 1
    assert out["success_rate"] == 0.5


def test_the_sandbox_crowd_stands_on_the_floor_and_off_the_places(shared_data: Callable[[str], Path],
                                                                 tmp_path: Path) -> None:
    """The TurtleBot sandbox (1.45 m between its pillars) has no room for a group of three
    standing in a ring: it was placed outside the walls, in the map's unknown space. Now the mix
    goes on without it (the benchmark's five people all on the floor), and the stander keeps
    off the places (one drawn 0.3 m from a place made every leg to it end short)."""
    from sage_robot.sim.spawn import STAND_OFF_PLACE_M

    path = shared_data("maps/tb3-sandbox/tb3_sandbox.yaml")
    args = argparse.Namespace(map=str(path), places=["auto", "6"], seed=7, waypoints="", people_wait=60.0,
                              fast=True, speed=None, pedestrians=5, people_model="auto")
    settings, places = bench_nav._settings(args, bench_nav._auto_places(args, str(tmp_path)))
    world, placed = bench_nav._world_that_fits(settings, bench_nav._scenario(()))
    people = world.crowd.people
    assert placed == len(people) == 5
    assert "group" not in {p.behaviour for p in people}
    for p in people:
        assert world.raycaster.is_free(p.x, p.y), (p.behaviour, p.x, p.y)
    stander = next(p for p in people if p.behaviour == "stander")
    assert min(math.hypot(stander.x - q.pose.x, stander.y - q.pose.y) for q in places) >= STAND_OFF_PLACE_M
