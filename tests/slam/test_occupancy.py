"""The occupancy grid from scans (``nav/slam/occupancy.py``): what a beam clears."""

from __future__ import annotations

import math

import numpy as np

from sage_robot.core.mapio import world_to_cell
from sage_robot.nav.slam.occupancy import OPEN_BORDER_M, OPEN_RUN_BEAMS, OccupancyMapper, open_space
from sage_robot.nav.slam.points import Scan

BEAMS = 360
ANGLES = -math.pi + 2 * math.pi / BEAMS * np.arange(BEAMS)
RANGE_MIN_M, RANGE_MAX_M = 0.15, 12.0
WALL_X_M = 2.0  # a wall across the x axis, the full height of the test
INTO_WALL_M = 0.02  # returns end this far inside the wall's face


def wall_scan(x: float, rng: np.random.Generator | None = None, noise: float = 0.0) -> Scan:
    """A scan from (x, 0) facing +x: the wall at WALL_X_M ahead, open space (no return) behind;
    readings under range_min are lost (inf), as the RPLIDAR driver reports them."""
    ranges = np.full(BEAMS, np.inf)
    ahead = np.cos(ANGLES) > 1e-6
    ranges[ahead] = (WALL_X_M + INTO_WALL_M - x) / np.cos(ANGLES[ahead])
    if rng is not None:
        ranges = ranges + rng.standard_normal(BEAMS) * noise * np.where(np.isfinite(ranges), ranges, 0.0)
    ranges[(ranges < RANGE_MIN_M) | (ranges > RANGE_MAX_M)] = np.inf
    return Scan(ranges.astype(np.float32), ANGLES, RANGE_MIN_M, RANGE_MAX_M, (0.0, 0.0, 0.0))


def wall_found(mapper: OccupancyMapper, x: float, half_height_m: float, band_m: float) -> float:
    """Of the wall's points the beams from (x, 0) hit within ``half_height_m`` of the axis, the
    fraction with an occupied cell within ``band_m`` of the wall's face."""
    grid = mapper.to_grid()
    ahead = np.cos(ANGLES) > 1e-6
    ys = (WALL_X_M - x) * np.tan(ANGLES[ahead])
    ys = ys[np.abs(ys) <= half_height_m]
    found = np.zeros(len(ys), dtype=bool)
    for dx in np.arange(-band_m, band_m + 1e-9, grid.resolution / 2):
        rows, cols = world_to_cell(grid, np.full(len(ys), WALL_X_M + INTO_WALL_M + dx), ys)
        found |= grid.data[rows, cols] == 100
    return float(found.mean())


def test_only_long_runs_between_far_returns_are_open_space() -> None:
    inf = np.inf
    r = np.array([1.0, inf, inf, inf, 2.0, inf, 3.0, 0.1, inf, inf, inf, 4.0, inf, inf, inf])
    got = open_space(r, ~np.isfinite(r))
    want = [0, 1, 1, 1, 0, 0, 0, 0, 0, 0, 0, 0, 1, 1, 1]  # a lone dropout; a run beside a 0.1 m return
    assert got.astype(int).tolist() == want
    assert OPEN_RUN_BEAMS == 3
    assert OPEN_BORDER_M > 0.1
    assert not open_space(np.ones(5), np.zeros(5, dtype=bool)).any()


def test_readings_lost_close_to_a_wall_do_not_clear_it() -> None:
    mapper = OccupancyMapper(0.05, RANGE_MAX_M)
    mapper.integrate_many([(0.0, 0.0, 0.0)] * 3, [wall_scan(0.0)] * 3)
    assert wall_found(mapper, 0.0, 1.0, 0.0) == 1.0
    # The robot brushes past the wall: 10 cm away, the beams ahead read under range_min.
    close = wall_scan(WALL_X_M - 0.1)
    assert (~np.isfinite(close.ranges[np.cos(ANGLES) > 0.8])).all()
    for _ in range(10):
        mapper.integrate((WALL_X_M - 0.1, 0.0, 0.0), close)
    assert wall_found(mapper, 0.0, 0.3, 0.0) == 1.0  # the wall ahead, where the readings were lost
    # Open space behind the robot (no returns, in long runs) is still cleared.
    grid = mapper.to_grid()
    xs, ys = np.meshgrid(np.arange(-4.0, -2.0, 0.05), np.arange(-0.5, 0.5, 0.05))
    rows, cols = world_to_cell(grid, xs.ravel(), ys.ravel())
    assert (grid.data[rows, cols] == 0).mean() > 0.5


def test_a_far_noisy_wall_stays_a_wall_when_the_range_noise_is_known() -> None:
    rng = np.random.default_rng(0)
    x = WALL_X_M - 9.0  # 9 m away: 1 % range noise is 9 cm
    scans = [wall_scan(x, rng, noise=0.01) for _ in range(30)]
    found = {}
    for fraction in (0.0, 0.01):
        mapper = OccupancyMapper(0.05, RANGE_MAX_M, range_noise_fraction=fraction)
        mapper.integrate_many([(x, 0.0, 0.0)] * len(scans), scans)
        found[fraction] = wall_found(mapper, x, 1.5, 0.1)
    assert found[0.01] > 0.93, found
    assert found[0.0] < found[0.01], found  # beams ending behind the wall cleared it


def test_too_close_and_error_readings_never_clear() -> None:
    """REP 117: -inf is a detection too close to measure and NaN an error; neither is open space."""
    for bad in (-np.inf, np.nan):
        mapper = OccupancyMapper(0.05, RANGE_MAX_M)
        mapper.integrate_many([(0.0, 0.0, 0.0)] * 3, [wall_scan(0.0)] * 3)
        ranges = np.full(BEAMS, bad, dtype=np.float32)
        blind = Scan(ranges, ANGLES, RANGE_MIN_M, RANGE_MAX_M, (0.0, 0.0, 0.0))
        for _ in range(10):
            mapper.integrate((WALL_X_M - 1.0, 0.0, 0.0), blind)
        assert wall_found(mapper, 0.0, 1.0, 0.0) == 1.0
