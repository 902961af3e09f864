"""Costmap layers, inflation, masks and the planner on hand-drawn grids and real maps."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sage_robot.core.mapio import read_map
from sage_robot.nav.costmap import (
    INSCRIBED,
    LETHAL,
    MAX_NON_OBSTACLE,
    NO_INFORMATION,
    OBSTACLE_PAD_M,
    WALL_PAD_M,
    Costmap,
    inflate,
)
from sage_robot.nav.planner import NoPath, path_length, plan

from ..support.grids import UNKNOWN, draw, fill, room

CORRIDOR = """
####################
#..................#
#..................#
#########..#########
#..................#
#..................#
####################
"""


def test_inflation_follows_nav2_decay() -> None:
    lethal = np.zeros((1, 40), dtype=bool)
    lethal[0, 0] = True
    cost, _dist = inflate(lethal, 0.05, 0.25, 0.55, 3.0)
    assert cost[0, 0] == LETHAL
    # distances run from a cell's centre to the lethal cell's face: cell i is (i - 0.5) cells away
    assert (cost[0, 1:6] == INSCRIBED).all()  # 0.025 .. 0.225 m: inscribed
    i = 8
    d = (i - 0.5) * 0.05
    assert cost[0, i] == int(MAX_NON_OBSTACLE * math.exp(-3.0 * (d - 0.25)))
    assert cost[0, 12] == 0  # 0.575 m > inflation radius
    assert np.all(np.diff(cost[0, 5:12].astype(int)) <= 0)  # decays outward


def test_unknown_space_is_not_free() -> None:
    cm = Costmap.from_grid(draw("#####\n#.?.#\n#####", 1.0), 0.25, 0.55, 3.0)
    assert cm.cost[1, 2] == NO_INFORMATION


def test_obstacle_layer_marks_and_raytrace_clears() -> None:
    cm = Costmap.from_grid(room(6.0, 4.0), 0.25, 0.55, 3.0)
    angles = np.array([0.0])
    cm.update_scan((1.0, 2.0, 0.0), angles, np.array([2.0]), 12.0)  # a person at (3, 2)
    assert cm.cost_at(3.0, 2.0)[()] == LETHAL
    assert cm.cost_at(3.0, 2.6)[()] < INSCRIBED  # 0.6 m to the side: passable
    # the person walks away: the beam now reaches the far wall and clears their cell
    cm.update_scan((1.0, 2.0, 0.0), angles, np.array([4.95]), 12.0)
    assert cm.cost_at(3.0, 2.0)[()] == 0
    assert cm.cost_at(5.99, 2.0)[()] == LETHAL  # the wall stays


def test_scan_hits_on_a_mapped_wall_seen_from_a_slightly_wrong_pose_are_the_wall() -> None:
    cm = Costmap.from_grid(room(6.0, 4.0), 0.25, 0.55, 3.0)
    wall_x = 5.95  # the east wall's face
    assert cm.distance_at(wall_x - 0.5, 2.0) == pytest.approx(0.5, abs=0.05)
    angles = np.linspace(-0.5, 0.5, 41)
    true_ranges = (wall_x - 1.0) / np.cos(angles)  # the east wall from (1, 2)
    cm.update_scan((0.93, 2.0, 0.0), angles, true_ranges, 12.0)  # localization 7 cm off
    assert cm.obstacles.any()  # the scan's wall is kept: relative to the robot it is exact
    # ... but not thickened like legs: a robot 0.5 m from where the scan puts the wall is free
    assert cm.distance_at(wall_x - 0.07 - 0.5, 2.0) > 0.5 - WALL_PAD_M - 0.08 > 0.5 - OBSTACLE_PAD_M - 0.08
    assert cm.cost_at(wall_x - 0.07 - 0.5, 2.0)[()] < INSCRIBED
    # a person 0.3 m from that wall is still an obstacle
    cm.update_scan((1.0, 2.0, 0.0), np.array([0.0]), np.array([4.6]), 12.0)
    assert cm.cost_at(5.62, 2.0)[()] == LETHAL  # the cell just beyond the return (the person's body)


def test_clear_obstacles() -> None:
    cm = Costmap.from_grid(room(6.0, 4.0), 0.25, 0.55, 3.0)
    cm.update_scan((1.0, 2.0, 0.0), np.array([0.0, 0.1]), np.array([2.0, 2.0]), 12.0)
    assert cm.obstacles.any()
    cm.clear_obstacles()
    assert not cm.obstacles.any()
    assert cm.cost_at(3.0, 2.0)[()] == 0


def test_plan_through_door_keeps_off_walls() -> None:
    cm = Costmap.from_grid(draw(CORRIDOR, 0.1, scale=5), 0.25, 0.55, 3.0)
    p = plan(cm, (1.0, 2.5), (9.0, 1.0))
    assert np.allclose(p.points[0], (1.0, 2.5))
    assert np.allclose(p.points[-1], (9.0, 1.0))
    assert (cm.cost_at(p.points[:, 0], p.points[:, 1]) < INSCRIBED).all()
    steps = np.hypot(*np.diff(p.points, axis=0).T)
    assert steps.max() < 0.06  # evenly resampled
    straight = math.hypot(9.0 - 1.0, 1.0 - 2.5)
    assert straight <= p.length_m < 2.0 * straight


def test_plan_blocked_raises_with_reason() -> None:
    walled = CORRIDOR.replace("#########..#########", "####################")
    cm = Costmap.from_grid(draw(walled, 0.1, scale=5), 0.25, 0.55, 3.0)
    with pytest.raises(NoPath, match="no free way"):
        plan(cm, (1.0, 2.5), (9.0, 1.0))


def test_plan_on_coarse_grid_never_crosses_walls(shared_data) -> None:
    grid = read_map(shared_data("maps/willow-full/willow-full.yaml"))
    cm = Costmap.from_grid(grid, 0.25, 0.55, 3.0)
    free = np.argwhere(cm.cost == 0)
    rng = np.random.default_rng(3)
    done = 0
    for _ in range(12):
        a, b = free[rng.integers(len(free), size=2)]
        s, g = cm.geom.to_world(*a), cm.geom.to_world(*b)
        try:
            p = plan(cm, (float(s[0]), float(s[1])), (float(g[0]), float(g[1])), max_cells=50_000)
        except NoPath:
            continue
        done += 1
        costs = cm.cost_at(p.points[:, 0], p.points[:, 1])
        assert not ((costs >= INSCRIBED) & (costs <= LETHAL)).any()  # never into or beside a wall
        assert (costs == NO_INFORMATION).sum() <= 2  # at most a stray unknown pixel of map noise
        assert p.length_m >= math.dist(s, g) - 1e-6
        assert path_length(p.points) == pytest.approx(p.length_m)
    assert done >= 3


def test_keepout_and_speed_masks_from_nav2(shared_data) -> None:
    base = "maps/nav2-depot/"
    grid = read_map(shared_data(base + "depot.yaml"))
    keep = read_map(shared_data(base + "depot_keepout.yaml"))
    speed = read_map(shared_data(base + "depot_speed.yaml"))
    cm = Costmap.from_grid(grid, 0.25, 0.55, 3.0, keep, speed)
    zone = keep.data >= 65
    assert zone.any()
    assert (cm.cost[zone] == LETHAL).all()
    limited = (speed.data > 0) & (speed.data <= 100)
    assert limited.any()
    assert np.allclose(cm.speed[limited], speed.data[limited] / 100.0)
    assert (cm.speed[speed.data == 0] == 1.0).all()


def test_far_scan_obstacles_are_forgotten() -> None:
    cm = Costmap.from_grid(room(20.0, 4.0), 0.25, 0.55, 3.0)
    cm.update_scan((2.0, 2.0, 0.0), np.array([0.0]), np.array([2.0]), 12.0)  # a mark at (4, 2)
    cm.update_scan((15.0, 2.0, 0.0), np.array([0.0]), np.array([1.0]), 12.0, forget_beyond_m=5.0)
    assert cm.cost_at(4.0, 2.0)[()] == 0  # 11 m away: forgotten
    assert cm.cost_at(16.0, 2.0)[()] == LETHAL


def test_scikit_image_backend_plans_the_same_way(monkeypatch) -> None:
    import sage_robot.nav.planner as planner_module

    cm = Costmap.from_grid(draw(CORRIDOR, 0.1, scale=5), 0.25, 0.55, 3.0)
    with_astar = plan(cm, (1.0, 2.5), (9.0, 1.0))
    monkeypatch.setattr(planner_module, "_astar_backend", lambda: None)  # as on aarch64
    with_mcp = plan(cm, (1.0, 2.5), (9.0, 1.0))
    assert (cm.cost_at(with_mcp.points[:, 0], with_mcp.points[:, 1]) < INSCRIBED).all()
    assert with_mcp.length_m == pytest.approx(with_astar.length_m, rel=0.1)


def test_a_robot_standing_in_unexplored_space_plans_its_way_out() -> None:
    """A SLAM map's unknown patch the robot has ended up in (willow-2010: every later goal
    failed "boxed in"): it plans out over the patch where its body fits; not through walls,
    and not across more than ESCAPE_UNKNOWN_M of it."""
    grid = room(10.0, 6.0, resolution=0.05)
    fill(grid, 3.0, 1.0, 6.0, 5.0, UNKNOWN)  # a 3 m x 4 m unseen patch (not a speckle)
    cm = Costmap.from_grid(grid, 0.25, 0.55, 3.0)
    inside = (3.8, 3.0)  # 0.8 m into the patch
    p = plan(cm, inside, (8.5, 3.0))
    assert p.points[0] == pytest.approx(inside)
    # straight out of the patch's west side (0.8 m) and round it through the 1 m gap above it
    # (about 8.8 m), not a longer detour
    assert p.length_m < 10.0
    cost = cm.cost_at(p.points[:, 0], p.points[:, 1])
    first_out = int(np.argmin(cost == NO_INFORMATION))
    assert (cost[first_out:] < INSCRIBED).all(), "the path wandered through the patch"
    deep = room(10.0, 6.0, resolution=0.05)
    fill(deep, 2.5, 1.0, 7.5, 5.0, UNKNOWN)
    with pytest.raises(NoPath, match="boxed in"):  # 2 m from any edge: further than it plans blind
        plan(Costmap.from_grid(deep, 0.25, 0.55, 3.0), (5.0, 3.0), (9.0, 3.0))
    walled = room(10.0, 6.0, resolution=0.05)
    fill(walled, 3.0, 1.0, 6.0, 5.0, UNKNOWN)
    fill(walled, 3.4, 2.6, 4.2, 3.4)  # a wall ring close round the robot: no way out
    fill(walled, 3.6, 2.8, 4.0, 3.2, UNKNOWN)
    with pytest.raises(NoPath, match="boxed in"):
        plan(Costmap.from_grid(walled, 0.25, 0.55, 3.0), inside, (8.5, 3.0))


def test_a_plan_from_the_edge_of_unexplored_space_goes_round_the_walls() -> None:
    """willow-2010 (issue #20): the robot's centre had drifted 5 cm into an unknown patch beside
    its path; every plan from there was a straight line to the goal through the patch and the
    walls beyond it (a smoothing shortcut from a start in unknown space counted as free), and the
    controller stopped at the first wall for good. The path leaves the patch and then keeps to
    passable cells."""
    grid = room(10.0, 6.0, resolution=0.05)
    fill(grid, 4.0, 2.6, 6.0, 3.4, UNKNOWN)  # an unseen patch 2 m x 0.8 m
    fill(grid, 2.0, 2.0, 8.0, 2.1)  # a wall below it, with a way round at each end
    cm = Costmap.from_grid(grid, 0.25, 0.55, 3.0)
    start, goal = (5.0, 3.35), (5.0, 1.0)  # 5 cm inside the patch's top edge; the goal below the wall
    p = plan(cm, start, goal)
    cost = cm.cost_at(p.points[:, 0], p.points[:, 1])
    unknown = cost == NO_INFORMATION
    first_out = int(np.argmin(unknown))
    assert first_out > 0, "the path starts in the patch"
    assert not unknown[first_out:].any(), "the path wandered through the patch"
    assert (cost[first_out:] < INSCRIBED).all(), "the path cuts through a wall or its inscribed zone"
    assert p.length_m > 5.0  # round an end of the wall, not the 2.35 m straight line through it


def test_a_plan_keeps_out_of_what_the_controllers_window_finds_impassable() -> None:
    """The global costmap and the controller's rolling window can disagree about an obstacle's
    pad (it depends on the marks around it, and the global costmap remembers more of them:
    willow-2010, issue #20, a box hard-padded in the window and soft-padded globally). Plans
    made with ``impassable_as(window)`` keep out of every cell the window finds impassable,
    and the global costmap is as it was afterwards."""
    grid = room(10.0, 6.0, resolution=0.05)
    cm = Costmap.from_grid(grid, 0.25, 0.55, 3.0)
    window = cm.window(5.0, 3.0, 4.0)
    window.obstacles[window.geom.to_cell(5.0, 3.0)] = True  # a return the global costmap lacks
    window.refresh()
    before = cm.cost.copy()
    def in_window(points: np.ndarray) -> np.ndarray:
        cost = window.cost_at(points[:, 0], points[:, 1])
        return cost[cost != NO_INFORMATION]  # (outside the window)

    with cm.impassable_as(window):
        p = plan(cm, (2.0, 3.0), (8.0, 3.0))
        assert (in_window(p.points) < INSCRIBED).all()
    assert (cm.cost == before).all()
    straight = plan(cm, (2.0, 3.0), (8.0, 3.0))  # without the window's view: straight through
    assert (in_window(straight.points) >= INSCRIBED).any()
    with cm.impassable_as(None):
        assert plan(cm, (2.0, 3.0), (8.0, 3.0)).length_m == pytest.approx(straight.length_m)


def test_a_narrow_cell_weighs_more_the_nearer_it_is_to_the_walls() -> None:
    # Across a narrow gap the costs differ by a few units only (240 in its middle, 248 at its
    # sides in the TurtleBot sandbox): each unit must weigh enough that the path keeps to the
    # middle instead of hugging the inside of a bend (issue #20).
    from sage_robot.nav.planner import NARROW_WEIGHT, weights_from_cost

    narrow = 186
    w = weights_from_cost(np.array([100, 186, 187, 240, 248, 252, 253, 254, 255], dtype=np.uint8), narrow)
    assert w[0] < w[1] < w[2]  # the ordinary cost slope, then the narrow step
    assert w[2] - w[1] >= NARROW_WEIGHT
    assert w[4] - w[3] >= 6.0  # eight units nearer the wall: worth more than a cell of detour each side
    assert w[3] < w[4] < w[5]
    assert np.isinf(w[6:]).all()  # inscribed, lethal, unknown
