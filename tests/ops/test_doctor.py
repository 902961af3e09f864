"""`sage doctor` on this machine (no robot) and with emulated devices attached."""

import subprocess
import sys

from sage_robot.app.doctor import run_checks
from sage_robot.core.config import load_profile
from sage_robot.hardware.emulators.rplidar import RplidarEmulator
from sage_robot.sim.mcu_pty import RealTimeMcu


def test_no_robot_attached_is_reported_clearly(tmp_path):
    profile = tmp_path / "p.yaml"
    profile.write_text(
        f"mcu: {{port: {tmp_path}/ttyACM9}}\nlidar: {{port: {tmp_path}/ttyUSB9}}\n"
        f"camera: {{device: {tmp_path}/video9}}\n"
    )
    out = subprocess.run(
        [sys.executable, "-m", "sage_robot.cli.main", "--profile", str(profile), "doctor"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 1, "a missing MCU is essential"
    text = out.stdout
    for name in ("mcu", "lidar", "camera", "network", "disk", "llm"):
        assert f"] {name}" in text
    assert "absent" in text
    assert "fix:" in text
    assert "Traceback" not in out.stdout + out.stderr


def test_emulated_mcu_and_lidar_are_found_and_talking():
    with RealTimeMcu() as mcu:
        lidar = RplidarEmulator(rev_hz=10.0)
        try:
            settings = load_profile(
                None, {"mcu": {"port": mcu.port_name}, "lidar": {"port": lidar.port_name}}
            )
            checks = {c.name: c for c in run_checks(settings)}
        finally:
            lidar.close()
    assert checks["mcu"].ok, checks["mcu"].detail
    assert "frames/s" in checks["mcu"].detail
    assert "ODOM" in checks["mcu"].detail
    assert checks["lidar"].ok, checks["lidar"].detail
    assert "spinning" in checks["lidar"].detail


def test_a_wake_head_that_is_not_there_is_named(tmp_path):
    settings = load_profile(None, {"voice": {"wake_heads": {"hey_jarvis": str(tmp_path / "gone.npz")}}})
    models = next(c for c in run_checks(settings) if c.name == "models")
    assert not models.ok
    assert "gone.npz: no such file" in models.detail
    assert models.fix
    assert "wake_heads" in models.fix
