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
    assert summary["scans"] == 30
    assert Path(summary["yaml"]).name == "mit-csail.yaml"
    assert Path(summary["pgm"]).exists()
    assert Path(summary["graph"]).exists()
    assert len(Path(summary["trajectory"]).read_text().splitlines()) == 31  # header + 30 scans


def test_malformed_log_is_one_clear_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.clf"
    bad.write_text("FLASER 3 1.0 2.0\n")
    assert main(["slam", "replay", str(bad), "--json"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"sage: error: {bad}:1: FLASER: expected 3 ranges")
    assert "\n" not in err


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


def test_sage_slam_runs_and_saves(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`sage slam --duration 5` with the whole sim_slam profile (web and Foxglove on free
    loopback ports, the simulation at 2x: "as fast as possible" let a quiet machine's simulator
    outrun the SLAM thread, which then mapped only a few scans): it maps and saves on exit."""
    profile = tmp_path / "profile.yaml"
    profile.write_text(
        "sim: {speed: 2.0}\n"
        "web: {host: 127.0.0.1, port: 0}\n"
        "ops: {foxglove_port: 0}\n"
        f"slam: {{out_dir: {tmp_path / 'unused'}, resolution_m: 0.1}}\n"
    )
    out = tmp_path / "maps"
    rc = main(["--profile", str(profile), "slam", "--duration", "5", "--out", str(out), "--name", "five"])
    text = capsys.readouterr().out
    assert rc == 0, text
    assert "web" in text.splitlines()[0]
    assert "slam" in text.splitlines()[0]
    from sage_robot.core.mapio import read_map

    grid = read_map(out / "five.yaml")
    assert grid.resolution == 0.1  # the profile's slam section reached the node
    assert (grid.data == 100).sum() > 50  # the walls around the dock
    assert len((out / "five.trajectory.txt").read_text().splitlines()) > 10  # 5 s of scans
    assert not (tmp_path / "unused").exists()  # --out wins over slam.out_dir


def test_bad_slam_setting_is_a_profile_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    profile = tmp_path / "profile.yaml"
    profile.write_text("slam: {keyframe_dist_m: -1}\n")
    assert main(["--profile", str(profile), "slam", "--duration", "5", "--headless"]) == 2
    err = capsys.readouterr().err.strip()
    assert "slam.keyframe_dist_m" in err
    assert "\n" not in err
