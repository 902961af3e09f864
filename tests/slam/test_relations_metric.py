"""The Kümmerle relation error against cases worked out by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sage_robot.nav.slam.carmen import LogFormatError
from sage_robot.nav.slam.relations import Relation, relation_error


def test_hand_computed_errors() -> None:
    stamps = np.array([10.0, 11.0, 12.0])
    # Estimated poses: 1 m forward, then a 90° left turn on the spot.
    poses = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 0.0, math.pi / 2]])
    rels = [
        # reference says 1.1 m forward: translational error 0.1 m, rotation 0
        Relation(10.0, 11.0, 1.1, 0.0, 0.0),
        # reference says turned 80°: rotational error 10°, translation 0
        Relation(11.0, 12.0, 0.0, 0.0, math.radians(80)),
        # reference from t=10 to t=12 is (1, 0.2, 90°): error = ⊖δ*⊕δ = R(-90°)(0, -0.2) → 0.2 m
        Relation(10.0, 12.0, 1.0, 0.2, math.pi / 2),
    ]
    err = relation_error(stamps, poses, rels)
    assert err.count == 3
    assert err.trans_mean_m == pytest.approx((0.1 + 0.0 + 0.2) / 3)
    assert err.trans_std_m == pytest.approx(np.std([0.1, 0.0, 0.2]))
    assert err.rot_mean_deg == pytest.approx(10.0 / 3)
    assert err.trans_max_m == pytest.approx(0.2)
    assert err.trans_median_m == pytest.approx(0.1)


def test_timestamps_match_the_nearest_scan() -> None:
    stamps = np.array([0.0, 0.5, 1.0])
    poses = np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [1.0, 0.0, 0.0]])
    err = relation_error(stamps, poses, [Relation(0.000004, 0.999996, 1.0, 0.0, 0.0)])
    assert err.trans_mean_m == pytest.approx(0.0, abs=1e-12)
    with pytest.raises(LogFormatError, match="from the nearest scan"):
        relation_error(stamps, poses, [Relation(0.2, 1.0, 1.0, 0.0, 0.0)])
