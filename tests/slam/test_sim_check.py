"""Simulation check: a scripted drive down the shipped building's corridor, ray-cast scans on
the true map, drifting odometry; the saved map matches the true walls and can be navigated."""

from __future__ import annotations

from sage_robot.bench.slam_sim import run_check


def test_map_of_the_default_building_matches_the_truth() -> None:
    result = run_check(max_length_m=25.0)
    assert result["odometry_end_error_m"] > 1.0  # the odometry alone drifts away
    assert result["trajectory_error_max_m"] < 0.1
    assert result["occupied_precision"] > 0.95  # SLAM walls lie on true walls
    assert result["occupied_recall"] > 0.3  # grazing far walls stay unknown at 12 m
    assert result["nav_planned"] is True
    assert result["nav_path_clear"] is True
