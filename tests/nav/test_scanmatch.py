"""Scan-to-map refinement: a scan cast from the true pose pulls a nearby guess onto it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sage_robot.core.geometry import wrap_angle, wrap_angles
from sage_robot.nav.scanmatch import SignedDistanceField, refine
from sage_robot.sim.raycast import GridRaycaster

from ..support.grids import draw
from .test_localization_control import FLOOR

ANGLES = -math.pi + 2 * math.pi / 360 * np.arange(360)
RANGE_MAX_M = 12.0
TRUTH = (4.3, 5.2, 0.4)  # in the open part of the floor, walls and a pillar in view
NOISE = 0.01  # 1 % range noise, as the simulator's lidar


@pytest.fixture(scope="module")
def floor():
    grid = draw(FLOOR, 0.05, scale=10)
    return grid, SignedDistanceField(grid), GridRaycaster(grid)


def _scan(caster, pose, seed=1):
    r = caster.cast(pose[0], pose[1], ANGLES + pose[2], RANGE_MAX_M)
    return r * (1.0 + NOISE * np.random.default_rng(seed).standard_normal(len(r)))


def _error(fix, truth=TRUTH):
    return math.hypot(fix.x - truth[0], fix.y - truth[1]), abs(wrap_angle(fix.theta - truth[2]))


def test_a_guess_a_few_cm_off_is_pulled_onto_the_truth(floor) -> None:
    _, sdf, caster = floor
    r = _scan(caster, TRUTH)
    for guess in [(4.36, 5.15, 0.42), (4.25, 5.26, 0.37), (4.3, 5.28, 0.4)]:
        fix = refine(sdf, guess, (0.0, 0.0, 0.0), ANGLES, r, RANGE_MAX_M)
        assert fix is not None
        dxy, dth = _error(fix)
        assert dxy < 0.02, (guess, dxy, math.degrees(dth))
        assert dth < math.radians(0.5), (guess, dxy, math.degrees(dth))
        assert fix.inliers > 300
        assert fix.rms_m < 0.05


def test_people_in_view_are_left_out(floor) -> None:
    _, sdf, caster = floor
    r = _scan(caster, TRUTH)
    # a crowd on one side: the beams of a 60 degree sector return at 1 m
    crowd = np.abs(wrap_angles(ANGLES - 1.0)) < math.radians(30)
    r[crowd] = 1.0
    fix = refine(sdf, (4.35, 5.16, 0.43), (0.0, 0.0, 0.0), ANGLES, r, RANGE_MAX_M)
    assert fix is not None
    assert _error(fix)[0] < 0.02


def test_a_scan_that_does_not_fit_is_not_trusted(floor) -> None:
    _, sdf, caster = floor
    r = _scan(caster, TRUTH)
    # a guess a metre off: the scan does not lie on the walls there
    assert refine(sdf, (5.3, 4.2, 0.4), (0.0, 0.0, 0.0), ANGLES, r, RANGE_MAX_M) is None
    # too few returns to rest on
    few = np.full_like(r, np.inf)
    few[:10] = r[:10]
    assert refine(sdf, TRUTH, (0.0, 0.0, 0.0), ANGLES, few, RANGE_MAX_M) is None
