"""`sage slam replay` and `sage bench slam` from the command line."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import pytest

from sage_robot.cli.main import main


def test_replay_writes_map_and_trajectory(
    shared_data: Callable[[str], Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log = shared_data("slam/mit-csail/mit-csail.clf")
    rc = main(["slam", "replay", str(log), "--limit", "30", "--out", str(tmp_path), "--json"])
    assert rc == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["scans"] == 30 and Path(summary["yaml"]).name == "mit-csail.yaml"
    assert Path(summary["pgm"]).exists() and Path(summary["graph"]).exists()
    assert len(Path(summary["trajectory"]).read_text().splitlines()) == 31  # header + 30 scans


def test_malformed_log_is_one_clear_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.clf"
    bad.write_text("FLASER 3 1.0 2.0\n")
    assert main(["slam", "replay", str(bad), "--json"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"sage: error: {bad}:1: FLASER: expected 3 ranges") and "\n" not in err


def test_bench_needs_a_reference(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "slam", "--log", str(tmp_path / "x.clf")]) == 2
    assert "--relations" in capsys.readouterr().err


def test_save_again_from_a_pose_graph(
    shared_data: Callable[[str], Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log = shared_data("slam/mit-csail/mit-csail.clf")
    assert main(["slam", "replay", str(log), "--limit", "20", "--out", str(tmp_path), "--json"]) == 0
    capsys.readouterr()
    graph = tmp_path / "mit-csail.graph.npz"
    assert (
        main(["slam", "save", "coarse", "--from", str(graph), "--out", str(tmp_path), "--resolution", "0.1"])
        == 0
    )
    from sage_robot.core.mapio import read_map

    assert read_map(tmp_path / "coarse.yaml").resolution == 0.1
    assert main(["slam", "save", "x", "--from", str(tmp_path / "none.graph.npz")]) == 2
    assert "pose graph file not found" in capsys.readouterr().err
