"""Detecting a reference made on a grid around the odometry, and the rounding floor it sets."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sage_robot.nav.slam.refcheck import reference_quantization, rounding_error

GRID_M = 0.05
ROT_GRID_DEG = 0.25


def _relations(rng: np.random.Generator, n: int, quantize: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(reference, odometry, truth) relative poses; the reference is the odometry plus the true
    correction rounded on a 5 cm grid turned by 30° (a world-frame grid) and 0.25° steps."""
    odo = np.column_stack((rng.uniform(0.1, 0.4, n), rng.normal(0, 0.02, n), rng.normal(0, 0.05, n)))
    corr = np.column_stack((rng.normal(0, 0.025, (n, 2)), rng.normal(0, math.radians(1.0), n)))
    truth = odo + corr
    if not quantize:
        return truth, odo, truth
    phi = math.radians(30.0)
    rot = np.array([[math.cos(phi), -math.sin(phi)], [math.sin(phi), math.cos(phi)]])
    world = corr[:, :2] @ rot.T
    snapped = (np.round(world / GRID_M) * GRID_M) @ rot
    step = math.radians(ROT_GRID_DEG)
    ref = odo + np.column_stack((snapped, np.round(corr[:, 2] / step) * step + math.radians(0.1)))
    return ref, odo, truth


def test_a_grid_reference_is_recognised_and_its_floor_matches_a_perfect_estimator() -> None:
    rng = np.random.default_rng(3)
    ref, odo, truth = _relations(rng, 3000, quantize=True)
    q = reference_quantization(ref, odo, truth, GRID_M, ROT_GRID_DEG)
    assert q.relations == 3000
    assert q.on_grid == pytest.approx(1.0)
    assert q.rot_on_grid == pytest.approx(1.0)
    # the zero cell: both world components within ±2.5 cm (σ 2.5 cm): about 0.68² of them
    assert 0.38 < q.equal_odometry < 0.55
    # the truth itself disagrees with the reference by the rounding; the floor predicts it
    assert q.estimate_error_m == pytest.approx(q.floor_m, rel=0.08)
    assert 0.012 < q.floor_m < 0.022
    # the odometry as the estimate: no offset, no floor, the full correction as error
    q_odo = reference_quantization(ref, odo, odo, GRID_M, ROT_GRID_DEG)
    assert q_odo.floor_m == 0.0
    assert q_odo.estimate_error_m > q.estimate_error_m


def test_the_covariance_split_recovers_each_side_s_noise() -> None:
    rng = np.random.default_rng(5)
    ref, odo, truth = _relations(rng, 20000, quantize=True)
    ref = ref + np.column_stack((rng.normal(0, 0.012, (len(ref), 2)), np.zeros(len(ref))))
    est = truth + np.column_stack((rng.normal(0, 0.009, (len(ref), 2)), np.zeros(len(ref))))
    q = reference_quantization(ref, odo, est, GRID_M, ROT_GRID_DEG)
    assert q.estimate_noise_m == pytest.approx((0.009, 0.009), abs=0.0015)
    assert q.reference_noise_m == pytest.approx((0.012, 0.012), abs=0.0025)
    assert q.floor_m < q.estimate_error_m


def test_a_continuous_reference_is_not_on_the_grid() -> None:
    ref, odo, truth = _relations(np.random.default_rng(4), 2000, quantize=False)
    q = reference_quantization(ref, odo, truth, GRID_M, ROT_GRID_DEG)
    assert q.on_grid < 0.2
    assert q.rot_on_grid < 0.2
    assert q.equal_odometry == 0.0
    assert q.estimate_error_m == pytest.approx(0.0, abs=1e-12)


def test_rounding_error_by_hand() -> None:
    # on grid points: nothing to round; half a cell along an axis: half a cell at 0°, less when turned
    assert rounding_error(np.array([[0.05, -0.10], [0.0, 0.0]]), GRID_M, orientations=1) == 0.0
    assert rounding_error(np.array([[0.02, 0.0]]), GRID_M, orientations=1) == pytest.approx(0.02)
    assert rounding_error(np.zeros((0, 2)), GRID_M) == 0.0
    assert reference_quantization(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3))).relations == 0
