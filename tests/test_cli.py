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


def test_the_service_unit_lets_the_motion_process_take_its_real_time_priority(tmp_path, capsys):
    profile = tmp_path / "p.yaml"
    profile.write_text("processes:\n  realtime:\n    motion: 30\n")
    assert main(["install-service", "--out", str(tmp_path / "a.service")]) == 0
    assert main(["--profile", str(profile), "install-service", "--processes",
                 "--out", str(tmp_path / "b.service")]) == 0
    default, custom = (tmp_path / "a.service").read_text(), (tmp_path / "b.service").read_text()
    assert "\nLimitRTPRIO=40\n" in default
    assert "\nLimitRTPRIO=30\n" in custom
    assert "up --mode tour\n" in default
    assert f"--profile {profile.resolve()} up --mode tour --processes\n" in custom
    # Zenoh's threads (processes.zenoh_realtime) need their priority too, when it is the highest
    profile.write_text("processes:\n  realtime:\n    motion: 30\n  zenoh_realtime: 35\n")
    assert main(["--profile", str(profile), "install-service", "--out", str(tmp_path / "c.service")]) == 0
    assert "\nLimitRTPRIO=35\n" in (tmp_path / "c.service").read_text()
