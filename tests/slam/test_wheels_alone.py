"""SLAM with the wheels alone (no gyro): the tracker's doubtful matches, and odometry edges that
trust the calibrated travel once the calibration's scale is known."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sage_robot.core.geometry import compose, relative
from sage_robot.nav.slam.engine import Slam, SlamConfig
from sage_robot.nav.slam.matcher import Match
from sage_robot.nav.slam.odomcal import OdometryCalibration
from sage_robot.nav.slam.points import Scan
from sage_robot.nav.slam.posegraph import KIND_ODOM, Edge

from .synth import corridor_loop, loop_path, simulate

Pose = tuple[float, float, float]


def _started(config: SlamConfig) -> tuple[Slam, Pose, Scan]:
    """A Slam that tracked two scans of the drawn corridor; the odometry pose and scan of a
    third one 0.1 m further on."""
    truth = loop_path(step_m=0.1)[:3]
    drive = simulate(corridor_loop(), truth, yaw_drift=0.0)
    slam = Slam(config, initial_pose=truth[0])
    for k in range(2):
        slam.add_scan(0.2 * k, drive.odom[k], drive.scans[k])
    return slam, drive.odom[2], drive.scans[2]


def _fake_matches(slam: Slam, matches: list[tuple[float, float] | None]) -> list[Pose]:
    """Make the tracker's matches these (each: a turn added to the prediction, and the inlier
    fraction), one per prediction it tries; returns the predictions."""
    predictions: list[Pose] = []

    def fake_track(q: object, predicted: Pose, view: object) -> Match | None:
        predictions.append(predicted)
        m = matches[len(predictions) - 1]
        if m is None:
            return None
        turn, inliers = m
        return Match(compose(predicted, (0.0, 0.0, turn)), inliers, inliers, np.eye(3))

    slam._track = fake_track  # type: ignore[method-assign]
    return predictions


@pytest.mark.parametrize(
    ("gate", "turn", "inliers", "believed"),
    [
        (0.1, 0.2, 0.4, False),  # doubtful and turned away: dead-reckoned
        (0.0, 0.2, 0.4, True),  # no gate (the engine's defaults)
        (0.1, 0.05, 0.4, True),  # doubtful, but near the odometry's turn
        (0.1, 0.2, 0.8, True),  # a good match may turn the robot (the wheels slipped)
    ],
)
def test_a_doubtful_match_turned_away_from_the_odometry_is_not_believed(
    gate: float, turn: float, inliers: float, believed: bool
) -> None:
    """A scan that fits the local map poorly fits a turned copy of it about as well (a robot
    turning in a doorway, Willow 2010 seed 0: 0.19 rad off, and the map after it 0.42 m)."""
    slam, odom, scan = _started(SlamConfig(doubtful_turn_gate_rad=gate))
    # every prediction the tracker tries matches turned by the same amount
    predictions = _fake_matches(slam, [(turn, inliers)] * 3)
    slam.add_scan(0.4, odom, scan)
    odometry = predictions[0]
    expected = compose(odometry, (0.0, 0.0, turn)) if believed else odometry
    assert slam.pose == pytest.approx(expected)
    assert slam.doubtful_turns == (0 if believed else 1)
    assert (slam.last_score > 0) == believed


def test_a_scan_that_no_guess_matched_well_enough_is_dead_reckoned_by_the_odometry() -> None:
    """A doubtful match makes the tracker try "as the last step" and "no motion" too; when the
    best of them is still below ``min_track_inliers`` the scan is dead-reckoned by the odometry,
    not by the guess: a guess is only as good as its match."""
    slam, odom, scan = _started(SlamConfig())
    # the odometry's prediction matches worst, "as the last step" a little better (still too poorly)
    predictions = _fake_matches(slam, [(0.0, 0.1), (0.0, 0.25), None])
    slam.add_scan(0.4, odom, scan)
    assert len(predictions) == 3
    assert predictions[1] != pytest.approx(predictions[0])
    assert slam.pose == pytest.approx(predictions[0])
    assert slam.last_score == 0.0


# The scale error gate: the drawn drive's calibration reads 0.2 % once it has its 5 stretches
# and 0.15 % at the end: edges made before its error fell to this are graded, later ones stiff.
KNOWN = 0.0017


def _wheels_drive(config: SlamConfig, scans: int = 100, errors: list[float] | None = None) -> Slam:
    """The drawn corridor driven with the wheels alone; ``errors`` gets the calibration's scale
    error when each keyframe's odometry edge was made."""
    truth = loop_path(step_m=0.2)[:scans]
    drive = simulate(corridor_loop(), truth)
    slam = Slam(config, initial_pose=truth[0])
    for k in range(len(truth)):
        edges = len(slam.graph.edges)
        slam.add_scan(0.2 * k, drive.odom[k], drive.scans[k])  # (the calibration learns first)
        if errors is not None:
            error = slam.odometry_calibration.scale_error
            errors.extend(error for e in slam.graph.edges[edges:] if e.kind == KIND_ODOM)
    return slam


@pytest.mark.parametrize("stiff", [False, True])
def test_wheel_odometry_edges_trust_the_calibrated_travel_once_its_scale_is_known(stiff: bool) -> None:
    """With ``wheel_travel_scale_error`` the wheels' odometry edges get the stiff x, y noise once
    the calibration's scale is known that well, and at every optimisation the calibration's
    latest travel; before, a noise between the stiff and the weak one as the scale's standard
    error falls; their heading keeps the wheels' weak noise and the calibration of its time.
    Without it they keep what they were made with."""
    cfg = SlamConfig(
        calibrate_odometry=True,
        gyro_odom_sigma_xy_m=0.005,
        gyro_odom_sigma_xy_fraction=0.03,
        wheel_travel_scale_error=KNOWN if stiff else 0.0,
        loop_min_travel_m=math.inf,  # nothing optimised before the end: the edges stay as made
    )
    made_at: list[float] = []  # the scale's standard error when each odometry edge was made
    slam = _wheels_drive(cfg, scans=240, errors=made_at)  # 44 m: a lap of the drawn corridor
    cal = slam.odometry_calibration
    assert cal.scale_error <= KNOWN
    assert slam.optimizations == 0
    edges = [e for e in slam.graph.edges if e.kind == KIND_ODOM][1:]  # (the first: no step)
    before = [(e.z, e.information.copy()) for e in edges]

    def sigmas(e: Edge) -> tuple[float, float, float]:
        return e.information[0, 0] ** -0.5, e.information[2, 2] ** -0.5, math.hypot(e.z[0], e.z[1])

    weak_th = [cfg.odom_sigma_theta_rad + cfg.odom_sigma_fraction * abs(e.z[2]) for e in edges]
    made = {"stiff": 0, "graded": 0, "weak": 0}
    for e, th, error in zip(edges, weak_th, made_at[1:], strict=True):
        sxy, sth, dist = sigmas(e)
        assert sth == pytest.approx(th)
        weak, tight = cfg.odom_sigma_xy_m + cfg.odom_sigma_fraction * dist, 0.005 + 0.03 * dist
        if not stiff or error == math.inf:
            assert sxy == pytest.approx(weak)
        else:  # stiff once the scale is known to KNOWN; before, stiffer as it becomes known
            assert sxy == pytest.approx(min(weak, tight * max(1.0, error / KNOWN)))
        kind = "stiff" if sxy == pytest.approx(tight) else "weak" if sxy == pytest.approx(weak) else "graded"
        made[kind] += 1
    # without it every edge is weak; with it, the ones made once the calibration had settled
    # are stiff, and some made before it were in between
    assert made["weak"] > 0, made
    assert (made["stiff"] > 0 and made["graded"] > 0) if stiff else made["weak"] == len(edges), made
    slam.finish()
    if not stiff:
        for e, (z, info) in zip(edges, before, strict=True):
            assert e.z == z
            assert np.array_equal(e.information, info)
        return
    raw = [relative(slam.keyframes[e.i].odom, slam.keyframes[e.j].odom) for e in edges]
    for e, r, (z, _), th in zip(edges, raw, before, weak_th, strict=True):
        assert e.z[:2] == pytest.approx(cal.correct(r)[:2], abs=1e-12)
        assert e.z[2] == z[2]
        sxy, sth, dist = sigmas(e)
        assert sxy == pytest.approx(0.005 + 0.03 * dist)
        assert sth == pytest.approx(th)


@pytest.mark.parametrize("spread", [0.002, 0.01])
def test_the_scale_error_is_the_readings_spread_over_the_root_of_their_count(spread: float) -> None:
    """Stretches of 2.5 m of odometry (2 % long) whose matched length is off by ``spread`` (a
    fraction, 1 sigma, the tracker's error): the scale's standard error after n of them is
    about spread / sqrt(n)."""
    rng = np.random.default_rng(7)
    cal = OdometryCalibration()
    everywhere = np.diag([1e4, 1e4, 1e5])
    pose = odom = (0.0, 0.0, 0.0)
    cal.observe(pose, odom, everywhere)  # the first stretch starts here
    stretch_m, n = 2.5, 40  # 100 m of stretches
    errors = []
    for _ in range(n):
        pose = compose(pose, (stretch_m / 1.02 * (1 + rng.normal(0.0, spread)), 0.0, 0.0))
        odom = compose(odom, (stretch_m, 0.0, 0.0))
        cal.observe(pose, odom, everywhere)
        errors.append(cal.scale_error)
    assert errors[2] == math.inf  # too few readings to tell
    assert errors[-1] == pytest.approx(spread / 1.02 / math.sqrt(n), rel=0.35)
