"""The absolute trajectory error after alignment (``nav/slam/trajectory.py``)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sage_robot.nav.slam.trajectory import align


def _turned(xy: np.ndarray, theta: float, shift: tuple[float, float], scale: float = 1.0) -> np.ndarray:
    c, s = math.cos(theta), math.sin(theta)
    return scale * xy @ np.array([[c, -s], [s, c]]).T + np.asarray(shift)


def test_a_moved_copy_of_the_truth_aligns_to_zero_error_and_says_how_it_was_moved() -> None:
    rng = np.random.default_rng(0)
    true = np.cumsum(rng.normal(0, 0.3, (200, 2)), axis=0)
    est = _turned(true, 0.3, (2.0, -1.0))  # the estimate, turned and shifted
    rigid = align(est, true)
    assert rigid.rmse_m < 1e-9
    assert rigid.rotation_rad == pytest.approx(-0.3)
    assert rigid.scale == 1.0
    back = _turned(est, rigid.rotation_rad, rigid.translation)
    assert np.allclose(back, true)


def test_an_estimate_that_reads_the_travel_long_shows_its_scale() -> None:
    rng = np.random.default_rng(1)
    true = np.cumsum(rng.normal(0, 0.3, (300, 2)), axis=0)
    est = _turned(true, -0.1, (0.5, 0.5), scale=1.005)  # 0.5 % long
    rigid, similar = align(est, true), align(est, true, with_scale=True)
    assert similar.scale == pytest.approx(1 / 1.005)
    assert similar.rmse_m < 1e-9
    assert rigid.rmse_m > 1e-3  # a rigid motion cannot take a scale error away


def test_noise_is_what_is_left_after_the_alignment() -> None:
    rng = np.random.default_rng(2)
    true = np.cumsum(rng.normal(0, 0.3, (2000, 2)), axis=0)
    noise = rng.normal(0, 0.02, true.shape)
    out = align(_turned(true + noise, 0.7, (3.0, 4.0)), true)
    assert out.rmse_m == pytest.approx(0.02 * math.sqrt(2), rel=0.05)  # σ per axis, both axes


def test_a_reflection_is_not_taken_for_a_rotation() -> None:
    true = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 2.0]])
    mirrored = true * np.array([1.0, -1.0])
    out = align(mirrored, true)
    assert out.rmse_m > 0.3  # a mirror image cannot be turned onto the original


def test_shapes_that_cannot_be_aligned_are_a_clear_error() -> None:
    with pytest.raises(ValueError, match="need two N×2 position arrays"):
        align(np.zeros((3, 2)), np.zeros((4, 2)))
    with pytest.raises(ValueError, match="N ≥ 2"):
        align(np.zeros((1, 2)), np.zeros((1, 2)))


def test_an_alignment_moves_poses_as_it_moves_positions() -> None:
    rng = np.random.default_rng(3)
    true = np.cumsum(rng.normal(0, 0.3, (50, 2)), axis=0)
    est = _turned(true, 0.4, (1.0, 2.0), scale=0.9)
    for fit in (align(est, true), align(est, true, with_scale=True)):
        moved = np.array([fit.apply((x, y, 0.1)) for x, y in est])
        want = fit.scale * _turned(est, fit.rotation_rad, (0.0, 0.0)) + fit.translation
        assert np.allclose(moved[:, :2], want)
        assert np.allclose(moved[:, 2], 0.1 + fit.rotation_rad)
    similar = align(est, true, with_scale=True)
    assert np.allclose(np.array([similar.apply((x, y, 0.0)) for x, y in est])[:, :2], true)
