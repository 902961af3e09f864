"""scripts/slam_keyframe_bias.py: its split of the matcher's along-travel error into scan points
adds up to the error the matcher made, and a drive too short to measure is a clear error."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path
from types import ModuleType

import pytest

from tests.slam.scripts import load_script

ROUNDING_MM = 0.001  # the JSON's rounding, per band


def load() -> ModuleType:
    return load_script("slam_keyframe_bias")


def args(**over: object) -> argparse.Namespace:
    base = {
        "map": None,
        "seed": 0,
        "length": 20.0,
        "backward": False,
        "rerender": 0.0,
        "equal_weights": False,
        "prior_sigma": 0.02,
        "heading_sigma": 0.002,
    }
    return argparse.Namespace(**{**base, **over})


@pytest.mark.parametrize("equal_weights", [False, True])
def test_the_split_adds_up_to_the_matchers_error(equal_weights: bool) -> None:
    out = load().measure(args(equal_weights=equal_weights))
    assert out["keyframes"] >= 20
    # one Gauss-Newton step from the truth with the match's pairings: within 0.1 mm of the match
    assert out["linear_sum_mm"] == pytest.approx(out["along_bias_mm"], abs=0.1)
    for split in ("by_range", "by_side"):
        bands = out[split]
        assert sum(bands.values()) == pytest.approx(out["linear_sum_mm"], abs=ROUNDING_MM * (len(bands) + 1))
    # exact ranges in a world of straight walls: the matcher is within millimetres of the truth
    assert abs(out["along_bias_mm"]) < 2.0
    assert out["along_sd_mm"] < 10.0


def test_matches_refined_with_equal_weights_are_split_as_they_were_made(
    shared_data: Callable[[str], Path],
) -> None:
    # The depot's rooms pin some matches in every direction: those are refined with every
    # pairing weighing the same, and the split weighs them so too.
    out = load().measure(args(map=str(shared_data("maps/nav2-depot/depot.yaml")), length=30.0))
    assert 0 < out["equal_weight_matches"] < out["keyframes"]
    assert out["linear_sum_mm"] == pytest.approx(out["along_bias_mm"], abs=0.1)


def test_a_drive_too_short_is_a_clear_error(capsys: pytest.CaptureFixture[str]) -> None:
    assert load().main(["--length", "0.5", "--rerender", "0"]) == 2
    assert "slam_keyframe_bias: error: no keyframe to measure" in capsys.readouterr().out
