"""Ray casting against small hand-drawn grids, circles and boxes (exact answers)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sage_robot.sim import raycast
from sage_robot.sim.raycast import GridRaycaster, ray_boxes, ray_circles

from ..support.grids import draw, grid_of

EAST, NORTH, WEST, SOUTH = 0.0, math.pi / 2, math.pi, -math.pi / 2

ROOM = """
##########
#........#
#........#
#...#....#
#........#
##########
"""  # 10 x 6 cells of 1 m; row 0 (bottom) is the last line


def test_distances_to_walls_in_a_room() -> None:
    rc = GridRaycaster(draw(ROOM, 1.0))
    # From (1.5, 1.5): east wall starts at x = 9, north wall at y = 5, west at x = 1, south at y = 1.
    r = rc.cast(1.5, 1.5, np.array([EAST, NORTH, WEST, SOUTH]), 20.0)
    assert r == pytest.approx([7.5, 3.5, 0.5, 0.5], abs=1e-3)


def test_a_pillar_blocks_and_diagonals_are_exact() -> None:
    rc = GridRaycaster(draw(ROOM, 1.0))
    # The pillar is the cell x in [4, 5), y in [2, 3): the fourth line of the drawing is row 2.
    r = rc.cast(2.5, 2.5, np.array([EAST]), 20.0)
    assert r[0] == pytest.approx(1.5, abs=1e-3)
    d = rc.cast(1.5, 1.5, np.array([math.pi / 4]), 20.0)[0]
    # 45° from (1.5, 1.5) reaches y = 5 (north wall) at x = 5.0: distance 3.5 * sqrt(2).
    assert d == pytest.approx(3.5 * math.sqrt(2), abs=1e-3)


def test_max_range_and_open_space_give_inf() -> None:
    rc = GridRaycaster(draw(ROOM, 1.0))
    assert math.isinf(rc.cast(1.5, 1.5, np.array([EAST]), 5.0)[0])
    open_grid = draw("""
        ....
        ....
    """, 1.0)
    assert np.isinf(GridRaycaster(open_grid).cast(1.0, 1.0, np.array([0.0, 1.0, 2.0]), 50.0)).all()


def test_origin_and_resolution_are_honoured() -> None:
    g = draw(ROOM, 0.1, origin=(-3.0, 2.0))
    rc = GridRaycaster(g)
    # Same geometry scaled by 0.1 and shifted.
    r = rc.cast(-3.0 + 0.15, 2.0 + 0.15, np.array([EAST, NORTH]), 5.0)
    assert r == pytest.approx([0.75, 0.35], abs=1e-4)


def test_rotated_map_origin() -> None:
    data = np.zeros((10, 10), dtype=np.int8)
    data[:, 9] = 100  # the wall at grid x in [9, 10)
    g = grid_of(data, 1.0, theta=math.pi / 2)
    # Grid +x points along map +y: from map (-0.5, 0.5), grid (0.5, 0.5); the wall is 8.5 ahead along map +y.
    r = GridRaycaster(g).cast(-0.5, 0.5, np.array([math.pi / 2]), 20.0)
    assert r[0] == pytest.approx(8.5, abs=1e-3)


def test_grazing_beams_match_a_full_trace(campus_raycaster: GridRaycaster) -> None:
    """The dense-sampling finish for grazing beams agrees with tracing every cell."""
    angles = np.linspace(-math.pi, math.pi, 360, endpoint=False)
    rng = np.random.default_rng(1)
    # (Positions off the cell grid lines: a ray running exactly along a cell boundary is degenerate.)
    for x, y in [(50.013, 40.021), (50.3, 57.51), (20.007, 40.2), (60.01, 62.93)] + [
        (float(rng.uniform(2, 98)), float(rng.uniform(39, 41))) for _ in range(3)
    ]:
        fast = campus_raycaster.cast(x, y, angles, 12.0)
        old = raycast.TRACE_ITERS
        raycast.TRACE_ITERS = 100_000
        try:
            exact = campus_raycaster.cast(x, y, angles, 12.0)
        finally:
            raycast.TRACE_ITERS = old
        both = np.isfinite(fast) & np.isfinite(exact)
        assert (np.isfinite(fast) == np.isfinite(exact)).mean() > 0.99
        assert np.abs(fast[both] - exact[both]).max() < 1e-3


def test_ray_circles() -> None:
    circles = np.array([[3.0, 0.0, 0.5], [0.0, 5.0, 1.0]])
    r = ray_circles(0.0, 0.0, np.array([EAST, NORTH, WEST]), circles)
    assert r == pytest.approx([2.5, 4.0, math.inf])
    assert ray_circles(3.0, 0.0, np.array([EAST]), circles)[0] == 0.0  # inside
    assert math.isinf(ray_circles(0.0, 0.0, np.array([EAST]), np.zeros((0, 3)))[0])


def test_ray_boxes() -> None:
    boxes = np.array([[4.0, 0.0, 2.0, 1.0, 0.0], [0.0, 4.0, 2.0, 1.0, math.pi / 2]])
    t, which = ray_boxes(0.0, 0.0, np.array([EAST, NORTH, SOUTH]), boxes)
    # East box spans x in [3, 5]; the north box is rotated 90°: spans y in [3, 5].
    assert t[:2] == pytest.approx([3.0, 3.0])
    assert list(which) == [0, 1, -1]
    assert math.isinf(t[2])


def test_clearance_is_distance_to_the_nearest_wall(campus_raycaster: GridRaycaster) -> None:
    rc = GridRaycaster(draw(ROOM, 1.0))
    assert rc.clearance(1.5, 1.5)[0] == pytest.approx(0.5, abs=0.01)
    assert rc.clearance(6.5, 2.5)[0] == pytest.approx(1.5, abs=0.01)
    assert math.isinf(rc.clearance(-5.0, -5.0)[0])  # outside the map
    # Middle of the 3 m east-west corridor of the default building.
    assert campus_raycaster.clearance(20.0, 40.0)[0] == pytest.approx(1.5, abs=0.05)
