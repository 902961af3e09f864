import subprocess
import sys

from sage_robot.cli.main import main


def test_help_at_every_level(capsys):
    assert main([]) == 0
    assert "sim" in capsys.readouterr().out
    assert main(["bench"]) == 0
    assert "bus" in capsys.readouterr().out


def test_version(capsys):
    assert main(["version"]) == 0
    assert "sage-robot" in capsys.readouterr().out


def test_bad_profile_is_one_line_no_traceback(tmp_path):
    bad = tmp_path / "p.yaml"
    bad.write_text("robot:\n  radius_m: wide\n")
    out = subprocess.run(
        [sys.executable, "-m", "sage_robot.cli.main", "--profile", str(bad), "doctor"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 1
    assert "robot.radius_m (line 2)" in out.stdout
    assert "Traceback" not in out.stdout + out.stderr


def test_sim_runs_headless_on_simulated_time():
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "sage_robot.cli.main",
            "sim",
            "--fast",
            "--headless",
            "--duration",
            "5",
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 0, out.stderr
    assert "simulated 5.0 s" in out.stdout
