"""Fixtures of the simulator's tests: hand-drawn grids and the default building (loaded once)."""

from __future__ import annotations

import pytest

from sage_robot.core.mapio import read_map
from sage_robot.core.msgs import OccupancyGrid
from sage_robot.core.paths import package_data


@pytest.fixture(scope="session")
def campus_grid() -> OccupancyGrid:
    return read_map(package_data("maps", "campus", "map.yaml"))


@pytest.fixture(scope="session")
def campus_raycaster(campus_grid: OccupancyGrid):
    from sage_robot.sim.raycast import GridRaycaster

    return GridRaycaster(campus_grid)
