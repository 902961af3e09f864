"""``sage bench slam --sim --seeds``: several seeded drives, each the same whether it runs alone
or beside others, summarised against issue #23's targets."""

from __future__ import annotations

from pathlib import Path

import pytest
from scipy.ndimage import binary_dilation

from sage_robot.bench.slam_seeds import TARGETS, parse_seeds, run_seeds
from sage_robot.cli.main import main
from sage_robot.core.errors import ConfigError
from sage_robot.core.mapio import write_map
from tests.support.grids import FREE, UNKNOWN, WALL, blank, fill

DRIVE_M = 6.0  # a short drive: the test checks the bench's plumbing, not the SLAM


def _room_with_a_pillar(tmp_path: Path) -> Path:
    g = blank(round(8.0 / 0.05), round(10.0 / 0.05), 0.05, value=UNKNOWN)
    fill(g, 0.5, 0.5, 9.5, 7.5, FREE)
    fill(g, 4.0, 2.5, 5.0, 4.0, UNKNOWN)
    free = g.data == FREE
    g.data[binary_dilation(free, iterations=4) & ~free] = WALL
    path = tmp_path / "room.yaml"
    write_map(g, path)
    return path


@pytest.mark.parametrize(
    ("text", "seeds"),
    [("0-3", [0, 1, 2, 3]), ("7", [7]), ("5,1,5", [5, 1]), ("2-4, 9", [2, 3, 4, 9]), ("3-3", [3])],
)
def test_seed_lists(text: str, seeds: list[int]) -> None:
    assert parse_seeds(text) == seeds


@pytest.mark.parametrize(
    ("text", "says"),
    [
        ("x", "'x' is not a seed"),
        ("3-1", "from low to high"),
        ("-2", "is not a seed"),
        ("1,,2", "'' is not"),
        ("0-5000", "more than"),
    ],
)
def test_bad_seed_lists_are_named(text: str, says: str) -> None:
    with pytest.raises(ConfigError, match=says):
        parse_seeds(text)


def test_seeds_side_by_side_give_what_each_gives_alone(tmp_path: Path) -> None:
    room = str(_room_with_a_pillar(tmp_path))
    alone = run_seeds([0, 1], jobs=1, max_length_m=DRIVE_M, map_path=room)
    beside = run_seeds([0, 1], jobs=2, max_length_m=DRIVE_M, map_path=room)
    assert [r["seed"] for r in beside["runs"]] == [0, 1]
    for a, b in zip(alone["runs"], beside["runs"], strict=True):
        assert {k: v for k, v in a.items() if k != "cpu_s"} == {k: v for k, v in b.items() if k != "cpu_s"}
    assert alone["runs"][0]["ate_aligned_rmse_m"] != alone["runs"][1]["ate_aligned_rmse_m"]  # two draws
    for key, bound in TARGETS.items():
        values = [r[key] for r in alone["runs"]]
        summary = alone[key]
        assert summary["mean"] == pytest.approx(sum(values) / 2, abs=1e-4)
        worst = min(values) if key == "walls_found" else max(values)
        assert summary["worst"] == pytest.approx(worst, abs=1e-4)
        met = [v >= bound if key == "walls_found" else v <= bound for v in values]
        assert summary["seeds_within_target"] == sum(met)
    assert (alone["map"], alone["route"], alone["gyro"]) == (room, "auto", False)


def test_command_line_errors_are_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "slam", "--seeds", "0-2"]) == 2
    assert "give it with --sim" in capsys.readouterr().err
    assert main(["bench", "slam", "--sim", "--seeds", "2-1"]) == 2
    assert "from low to high" in capsys.readouterr().err
    assert main(["bench", "slam", "--sim", "--seeds", "0", "--jobs", "0"]) == 2
    assert "--jobs 0" in capsys.readouterr().err
    missing = tmp_path / "none.yaml"
    assert main(["bench", "slam", "--sim", "--map", str(missing), "--seeds", "0-1", "--jobs", "2"]) == 2
    err = capsys.readouterr().err
    assert "no such map file" in err
    assert "Traceback" not in err


def test_drives_that_do_not_finish_are_stopped(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The wait for the drives has a bound: past it the workers are stopped and it says so."""
    from sage_robot.bench import slam_seeds
    from sage_robot.core.errors import SageError

    room = str(_room_with_a_pillar(tmp_path))
    monkeypatch.setattr(slam_seeds, "MAX_DRIVE_S", 0.2)  # a drive (and its worker's start) takes longer
    with pytest.raises(SageError, match=r"did not finish within 0\.2 s"):
        run_seeds([0, 1], jobs=2, max_length_m=DRIVE_M, map_path=room)
