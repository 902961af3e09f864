"""SLAM in simulation against exact ground truth: small maps driven by the automatic route,
with the robot's noisy lidar, drifting odometry, walking people and clutter (all seeded)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest
import yaml
from scipy.ndimage import binary_dilation

from sage_robot.bench.slam_sim import run_check
from sage_robot.core.errors import ConfigError
from sage_robot.core.mapio import write_map
from tests.support.grids import FREE, UNKNOWN, WALL, blank, fill

WALL_M = 0.2
ATE_BOUND_M = 0.05  # the bounds: trajectory and wall distance within 5 cm...
WALL_DISTANCE_BOUND_M = 0.05
WALLS_FOUND_MIN = 0.95  # ...and 95 % of the walls the lidar saw mapped
SEEDS = (0, 1, 2, 3)
MEAN_KEYS = ("ate_rmse_m", "wall_distance_mean_m", "walls_found")


def _two_rooms_and_a_corridor(tmp_path: Path) -> Path:
    """Two 6 × 6 m rooms joined by a bare 12 m × 2 m corridor (walls 0.2 m thick)."""
    g = blank(round(10.0 / 0.05), round(25.0 / 0.05), 0.05, value=UNKNOWN)
    fill(g, 0.5, 2.0, 6.5, 8.0, FREE)
    fill(g, 6.5, 4.0, 18.5, 6.0, FREE)
    fill(g, 18.5, 2.0, 24.5, 8.0, FREE)
    free = g.data == FREE
    g.data[binary_dilation(free, iterations=round(WALL_M / 0.05)) & ~free] = WALL
    path = tmp_path / "corridor.yaml"
    write_map(g, path)
    return path


def _assert_within_bounds(result: dict[str, object]) -> None:
    assert result["ate_rmse_m"] <= ATE_BOUND_M, result  # type: ignore[operator]
    assert result["wall_distance_mean_m"] <= WALL_DISTANCE_BOUND_M, result  # type: ignore[operator]
    assert result["walls_found"] >= WALLS_FOUND_MIN, result  # type: ignore[operator]


def test_slam_on_a_drawn_building_with_a_bare_corridor(tmp_path: Path) -> None:
    """One seeded drive is one draw of the noise (its ATE spreads over 0.02–0.07 m from seed
    to seed): the issue's bounds are checked on the mean of four."""
    path = _two_rooms_and_a_corridor(tmp_path)
    results = [run_check(map_path=path, seed=seed) for seed in SEEDS]
    for result in results:
        assert result["route"] == "auto"
        assert result["distance_m"] > 25.0  # both rooms, the corridor twice  # type: ignore[operator]
        assert result["odometry_end_error_m"] > 0.3  # the odometry alone is lost  # type: ignore[operator]
        assert result["people"] >= 1
        assert result["clutter"] >= 1
        assert result["nav_planned"] is True
        assert result["nav_path_clear"] is True
        # the best rigid fit can only lower the error; a scale fit on top lowers it further
        aligned = (result["ate_scale_aligned_rmse_m"], result["ate_aligned_rmse_m"], result["ate_rmse_m"])
        assert aligned == tuple(sorted(aligned)), result
        assert 0.95 < result["travel_scale"] < 1.05
    mean = {key: sum(r[key] for r in results) / len(results) for key in MEAN_KEYS}
    _assert_within_bounds(mean)


def test_slam_with_the_gyro_on_a_drawn_building(tmp_path: Path) -> None:
    """``sage bench slam --sim --imu``: the odometry turns with the robot's gyro (its scale
    error, residual bias and noise); the same bounds, on the mean of the same four seeds."""
    path = _two_rooms_and_a_corridor(tmp_path)
    results = [run_check(map_path=path, seed=seed, gyro=True) for seed in SEEDS]
    assert all(r["gyro"] is True for r in results)
    mean = {key: sum(r[key] for r in results) / len(results) for key in MEAN_KEYS}
    _assert_within_bounds(mean)


def test_slam_on_the_turtlebot_sandbox_map(shared_data: Callable[[str], Path]) -> None:
    result = run_check(map_path=shared_data("maps/tb3-sandbox/tb3_sandbox.yaml"))
    _assert_within_bounds(result)
    assert result["return_error_m"] <= ATE_BOUND_M  # back at the start: the map kept its shape  # type: ignore[operator]


def test_same_seed_same_run(tmp_path: Path) -> None:
    path = _two_rooms_and_a_corridor(tmp_path)
    a = run_check(max_length_m=6.0, map_path=path, seed=3)
    b = run_check(max_length_m=6.0, map_path=path, seed=3)
    a.pop("cpu_s"), b.pop("cpu_s")
    assert a == b


def test_bad_input_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="no such map"):
        run_check(map_path=tmp_path / "missing.yaml")
    with pytest.raises(ConfigError, match="--route corridor"):
        run_check(map_path=_two_rooms_and_a_corridor(tmp_path), route="corridor")
    boxed = tmp_path / "boxed.yaml"
    write_map(blank(20, 20, 0.05, value=WALL), boxed)
    with pytest.raises(ConfigError, match="no free space"):
        run_check(map_path=boxed)


def test_a_map_saved_turned_is_driven_in_its_image_frame(tmp_path: Path) -> None:
    """``origin: [x, y, yaw]`` with a yaw only turns the whole building in the map frame:
    the drive, the mapping and every score are those of the same map saved level."""
    level = _two_rooms_and_a_corridor(tmp_path)
    turned = tmp_path / "turned.yaml"
    meta = yaml.safe_load(level.read_text())
    meta["origin"][2] = 0.7
    meta["image"] = str(level.with_suffix(".pgm"))
    turned.write_text(yaml.safe_dump(meta))
    a = run_check(max_length_m=6.0, map_path=level, seed=1)
    b = run_check(max_length_m=6.0, map_path=turned, seed=1)
    for r in (a, b):
        r.pop("cpu_s"), r.pop("map")
    assert a == b
