"""The rounding-cell metric: distance of an estimated relation to the cell that a reference
rounded on a turned 5 cm / 0.25° grid stands for."""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from sage_robot.nav.slam.cells import (
    cell_errors,
    cell_score,
    grid_heading,
    offset_directions,
)
from sage_robot.nav.slam.relations import error_parts

STEP_M = 0.05
ROT_STEP = math.radians(0.25)


def _turn(phi: float, v: tuple[float, float]) -> tuple[float, float]:
    c, s = math.cos(phi), math.sin(phi)
    return (c * v[0] - s * v[1], s * v[0] + c * v[1])


def test_cell_distance_by_hand() -> None:
    phi = math.radians(30.0)  # the first pose's heading in the grid's frame
    ref = (1.0, 0.2, 0.1)
    cases = [
        # (estimate minus reference in the grid's frame (m), rotation minus reference (deg))
        ((0.01, -0.02), 0.1),  # inside: 1 and 2 cm < 2.5 cm, 0.1° < 0.125°
        ((0.04, 0.0), 0.2),  # 1.5 cm beyond the +x side; 0.075° beyond the half step
        ((-0.03, 0.045), -0.125),  # beyond a corner: (0.5 cm, 2 cm); rotation on the edge
    ]
    est = []
    for (ux, uy), dth in cases:
        dx, dy = _turn(-phi, (ux, uy))  # back into the first pose's frame
        est.append((ref[0] + dx, ref[1] + dy, ref[2] + math.radians(dth)))
    trans, rot = cell_errors(np.array([ref] * 3), np.array(est), np.full(3, phi), STEP_M, ROT_STEP)
    assert trans == pytest.approx([0.0, 0.015, math.sqrt(0.005**2 + 0.02**2)], abs=1e-12)
    assert np.degrees(rot) == pytest.approx([0.0, 0.075, 0.0], abs=1e-9)
    # In the wrong frame (the grid taken as the first pose's axes) the same 4 cm along the
    # grid's x is 3.46 cm along x and 2 cm along y: 0.96 cm outside, not 1.5 cm.
    wrong, _ = cell_errors(np.array([ref]), np.array([est[1]]), np.zeros(1), STEP_M, ROT_STEP)
    assert wrong[0] == pytest.approx(0.04 * math.cos(phi) - 0.025, abs=1e-12)


def test_the_grid_heading_is_read_from_the_reference_offsets() -> None:
    psi = math.radians(20.0)  # the grid's heading in the map frame
    heading = np.radians([0.0, 90.0, -135.0, 10.0, 50.0])  # first poses' headings (map frame)
    grid_vectors = [(0.05, 0.0), (0.05, 0.05), (0.0, -0.10), (0.10, 0.05), (0.0, 0.0)]
    odo = np.zeros((5, 3))
    ref = np.zeros((5, 3))
    for k, g in enumerate(grid_vectors):
        ref[k, :2] = _turn(psi - heading[k], g)  # grid → map → first pose's frame
    got = offset_directions(ref, odo, heading, STEP_M)
    # one cell along x, one along the diagonal, two along -y: all say 20°; √5 cells (26.6° or
    # 63.4°) and no offset say nothing
    assert np.degrees(got[:3]) == pytest.approx([20.0, 20.0, 20.0], abs=1e-9)
    assert np.isnan(got[3:]).all()
    # averaged modulo 90°: 40° and -50° are the same grid
    mean = grid_heading(np.arange(3.0), np.radians([40.0, -50.0, np.nan]))
    assert np.degrees(mean) == pytest.approx([40.0, 40.0, 40.0], abs=1e-9)
    assert (grid_heading(np.arange(2.0), np.full(2, np.nan)) == 0.0).all()


def _rounded_reference(
    rng: np.random.Generator, n: int, psi: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(reference, odometry, truth, map heading): the reference is the odometry plus the true
    correction rounded on a 5 cm grid whose heading in the map frame is ``psi`` (per relation)
    and on 0.25° steps, as the MIT CSAIL relations were made."""
    odo = np.column_stack((rng.uniform(0.1, 0.4, n), rng.normal(0, 0.02, n), rng.normal(0, 0.05, n)))
    heading = rng.uniform(-math.pi, math.pi, n)
    phi = heading - psi
    grid_corr = rng.normal(0, 0.03, (n, 2))
    rot_corr = rng.normal(0, math.radians(1.0), n)
    c, s = np.cos(-phi), np.sin(-phi)  # grid frame → first pose's frame

    def local(v: np.ndarray) -> np.ndarray:
        return np.column_stack((c * v[:, 0] - s * v[:, 1], s * v[:, 0] + c * v[:, 1]))

    truth = odo + np.column_stack((local(grid_corr), rot_corr))
    snapped = np.round(grid_corr / STEP_M) * STEP_M
    ref = odo + np.column_stack((local(snapped), np.round(rot_corr / ROT_STEP) * ROT_STEP))
    return ref, odo, truth, heading


def test_a_perfect_estimator_is_inside_every_cell() -> None:
    rng = np.random.default_rng(7)
    n = 600
    ref, odo, truth, heading = _rounded_reference(rng, n, np.full(n, math.radians(20.0)))
    stamps = np.arange(n, dtype=np.float64)
    score = cell_score(ref, odo, truth, heading, stamps, STEP_M, ROT_STEP)
    assert score.relations == n
    assert score.inside == 1.0
    assert score.trans_mean_m == 0.0
    assert score.rot_mean_deg == 0.0
    assert score.heading_range_deg == pytest.approx((20.0, 20.0), abs=1e-9)
    # ...where Kümmerle's error of the same estimator is the rounding
    trans, rot = error_parts(ref, truth)
    assert 0.012 < trans.mean() < 0.022
    assert math.degrees(rot.mean()) == pytest.approx(0.0625, abs=0.01)
    # 2 cm of error along the first pose's x: many cells left, by at most 2 cm
    off = truth + np.array([0.02, 0.0, 0.0])
    worse = cell_score(ref, odo, off, heading, stamps, STEP_M, ROT_STEP)
    assert 0.2 < worse.inside_trans < 0.8
    assert worse.inside_rot == 1.0
    assert 0.0 < worse.trans_mean_m < 0.02


def test_a_slowly_turning_grid_is_followed() -> None:
    rng = np.random.default_rng(8)
    n = 800
    psi = np.linspace(0.0, math.radians(-10.0), n)  # the grid turns 10° against the map frame
    ref, odo, truth, heading = _rounded_reference(rng, n, psi)
    score = cell_score(ref, odo, truth, heading, np.arange(n, dtype=np.float64), STEP_M, ROT_STEP)
    assert score.heading_range_deg[0] == pytest.approx(-10.0, abs=0.8)
    assert score.heading_range_deg[1] == pytest.approx(0.0, abs=0.8)
    assert score.inside > 0.97
    assert score.trans_mean_m < 1e-4
    # taking the grid as fixed in the map frame loses cells at the end of the run
    fixed, _ = cell_errors(ref, truth, heading, STEP_M, ROT_STEP)
    assert (fixed > 0).mean() > 1 - score.inside


def test_mit_csail_odometry_is_inside_exactly_where_the_reference_equals_it(
    shared_data: Callable[[str], Path],
) -> None:
    from sage_robot.bench.slam import _reference_check
    from sage_robot.nav.slam.carmen import read_log
    from sage_robot.nav.slam.relations import read_relations

    log = read_log(shared_data("slam/mit-csail/mit-csail.clf"))
    rels = read_relations(shared_data("slam/mit-csail/mit-csail.relations"))
    stamps = np.array([s.stamp for s in log.scans])
    odo = np.array([s.odom for s in log.scans])
    # The raw odometry as the estimate: a reference offset of at least one 5 cm cell is
    # outside the cell whatever its heading, a zero offset inside.
    out = _reference_check(stamps, odo, odo, rels)
    assert out["short_relations"] == 1044
    assert out["long_relations"] == 128
    assert out["cell_relations"] == 1044
    assert out["cell_inside_trans"] == pytest.approx(out["reference_equal_odometry"], abs=1e-3)
    assert out["cell_trans_mean_m"] > 0.01


def test_bench_prints_the_cell_scores(
    shared_data: Callable[[str], Path], capsys: pytest.CaptureFixture[str]
) -> None:
    from sage_robot.cli.main import main

    log = shared_data("slam/mit-csail/mit-csail.clf")
    rels = shared_data("slam/mit-csail/mit-csail.relations")
    rc = main(["bench", "slam", "--log", str(log), "--relations", str(rels), "--limit", "150", "--json"])
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    assert out["cell_relations"] == out["short_relations"] == out["relations"] > 0
    assert out["long_relations"] == 0  # the first 150 scans hold no revisit
    # the distance to a box is never more than to its centre
    assert 0.0 <= out["cell_trans_mean_m"] < out["short_trans_error_mean_m"]
    # SLAM lands inside more cells than the raw odometry (inside exactly where the reference
    # equals it, see the test above)
    assert out["cell_inside_trans"] > out["reference_equal_odometry"]
