"""Round trips of the simulator's messages and the DOA angle convention."""

from __future__ import annotations

import math

import pytest

from sage_robot.core.msgs import from_dict, to_dict
from sage_robot.core.msgs.sim import (
    LowObstacle,
    People,
    Person,
    SpeakerBearing,
    bearing_to_doa_deg,
    doa_deg_to_bearing,
)

SAMPLES = [
    Person(3, 1.5, -2.0, 0.3, 1.1, "approacher", 0.25),
    People(12.5, (Person(0, 1.0, 2.0), Person(1, 3.0, 4.0, behaviour="group"))),
    People(0.0),
    SpeakerBearing(4.0, True, 90.0, 1.2, 3),
    SpeakerBearing(4.0, False),
    LowObstacle("bench1", 10.0, 20.0, 1.6, 0.45, 0.5, 0.45, "bench"),
]


@pytest.mark.parametrize("msg", SAMPLES, ids=lambda m: type(m).__name__)
def test_round_trip(msg: object) -> None:
    assert from_dict(to_dict(msg)) == msg


def test_doa_convention_matches_the_seed() -> None:
    # 0° behind, 90° left, 180° front, 270° right.
    assert bearing_to_doa_deg(0.0) == pytest.approx(180.0)
    assert bearing_to_doa_deg(math.pi / 2) == pytest.approx(90.0)
    assert bearing_to_doa_deg(-math.pi / 2) == pytest.approx(270.0)
    assert bearing_to_doa_deg(math.pi) % 360.0 == pytest.approx(0.0)
    for b in (-3.0, -1.0, 0.0, 0.5, 2.9):
        assert doa_deg_to_bearing(bearing_to_doa_deg(b)) == pytest.approx(b)
