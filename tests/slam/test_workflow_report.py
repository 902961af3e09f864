"""The quality report at the end of ``sage slam replay`` (issue #23): loops closed, residuals of
the optimised pose graph per edge kind, keyframes, distance; also under ``"quality"`` in --json."""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from sage_robot.cli.main import main
from sage_robot.core.geometry import compose
from sage_robot.nav.slam.engine import Slam
from sage_robot.nav.slam.posegraph import KIND_LOOP, KIND_ODOM, KIND_SCAN
from sage_robot.nav.slam.replay import edge_residuals, format_report, quality_report

from .synth import corridor_loop, loop_path, simulate

STEP_M = 0.35  # travel between scans (m), as test_loop_closure.py
LIMIT = 100  # scans of the MIT CSAIL log replayed from the command line


def _lap() -> Slam:
    truth = loop_path(step_m=STEP_M)
    drive = simulate(corridor_loop(), truth, yaw_drift=0.02)
    slam = Slam(initial_pose=truth[0])
    for k, (odom, scan) in enumerate(zip(drive.odom, drive.scans, strict=True)):
        slam.add_scan(STEP_M * k, odom, scan)
    return slam


def test_report_of_a_closed_lap() -> None:
    slam = _lap()
    report = quality_report(slam)
    assert report["loop_closures"] == slam.loop_closures >= 1
    edges = report["edges"]
    assert edges[KIND_LOOP]["count"] == slam.loop_closures
    assert edges[KIND_ODOM]["count"] == report["keyframes"] - 1  # one per keyframe after the first
    assert edges[KIND_SCAN]["count"] >= report["keyframes"] - 1  # matched against several earlier ones
    truth = np.array(loop_path(step_m=STEP_M))[:, :2]
    driven = float(np.hypot(*np.diff(truth, axis=0).T).sum())  # the drawn path's length (m)
    assert abs(report["distance_m"] - driven) < 0.02 * driven
    # After optimisation the loop edges agree with the graph to centimetres and a fraction of a degree.
    assert edges[KIND_LOOP]["residual_m"]["max"] < 0.05
    assert edges[KIND_LOOP]["residual_deg"]["max"] < 1.0
    for e in edges.values():
        assert 0 <= e["residual_m"]["mean"] <= e["residual_m"]["max"]
        assert 0 <= e["chi"]["mean"] <= e["chi"]["max"]
    text = format_report(report)
    assert f"{slam.loop_closures} loops closed" in text
    assert "loop  edges:" in text


def test_residuals_measure_what_the_graph_does_not_honour() -> None:
    """Move one node by a known offset: its edges' residuals are that offset."""
    slam = _lap()
    graph = slam.graph
    k = len(graph.poses) // 2
    before, _ = edge_residuals(graph)
    graph.poses[k] = compose(graph.poses[k], (0.3, 0.0, 0.0))  # 30 cm forward in its own frame
    after, rot = edge_residuals(graph)
    touching = np.array([(e.i == k) != (e.j == k) for e in graph.edges])
    assert np.all(np.abs(after[~touching] - before[~touching]) < 1e-12)
    assert np.all(np.abs(after[touching] - 0.3) < 0.05 + before[touching])
    assert np.all(rot[touching] < math.radians(5))


def test_replay_prints_the_report(
    shared_data: Callable[[str], Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log = shared_data("slam/mit-csail/mit-csail.clf")
    assert main(["slam", "replay", str(log), "--limit", str(LIMIT), "--out", str(tmp_path), "--json"]) == 0
    quality = json.loads(capsys.readouterr().out)["quality"]
    assert quality["keyframes"] >= 2
    assert quality["distance_m"] > 0
    assert quality["edges"][KIND_ODOM]["count"] == quality["keyframes"] - 1
    assert set(quality["edges"]) == {KIND_ODOM, KIND_SCAN, KIND_LOOP}

    assert main(["slam", "replay", str(log), "--limit", str(LIMIT), "--out", str(tmp_path)]) == 0
    captured = capsys.readouterr()
    lines = captured.out.splitlines()
    assert lines[-5].startswith(f"quality: {quality['keyframes']} keyframes over {quality['distance_m']} m")
    assert lines[-1].strip().startswith("loop  edges:")
    assert "SLAM:" in captured.err  # the progress bar (tqdm, on stderr)
