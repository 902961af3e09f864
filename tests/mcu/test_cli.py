"""`sage mcu monitor` / `sage mcu drive` against the firmware model on a real pty, and
port finding."""

from __future__ import annotations

import os
import time

import pytest

from sage_robot.cli.main import main
from sage_robot.core.errors import DeviceNotConnectedError
from sage_robot.hardware.mcu.port import find_port, open_port
from sage_robot.sim.firmware import FirmwareModel
from sage_robot.sim.mcu_pty import PtyMcu, RealTimeMcu

from ..support.waits import wait_until


def test_drive_sends_a_bounded_clamped_command_then_stops(capsys: pytest.CaptureFixture[str]):
    with RealTimeMcu() as mcu:
        rc = main(["mcu", "drive", "--port", mcu.port_name, "--v", "0.3", "--seconds", "0.6"])
        fw = mcu.firmware
        assert rc == 0
        # stopped at the end (the model's thread reads the pty every 10 ms)
        wait_until(lambda: fw.last_command == (0.0, 0.0), "the stop at the end of the drive")
        assert fw.rx.frames >= 0.6 * 10  # re-sent at >= 10 Hz
        assert mcu.floor.pose[0] > 0.05
    out = capsys.readouterr().out
    assert "driving v=0.3 m/s" in out
    assert "stopped; last odometry x=+0." in out


def test_drive_never_reverses_and_refuses_long_drives(capsys: pytest.CaptureFixture[str]):
    with RealTimeMcu() as mcu:
        assert main(["mcu", "drive", "--port", mcu.port_name, "--v", "-1", "--seconds", "0.2"]) == 0
        assert mcu.floor.pose[0] == 0.0
    assert "clamped to the profile's limits: v=0 m/s" in capsys.readouterr().out
    assert main(["mcu", "drive", "--sim", "--seconds", "60"]) == 2
    assert "--seconds must be in (0, 10]" in capsys.readouterr().err


def test_monitor_prints_rates_values_and_errors(capsys: pytest.CaptureFixture[str]):
    assert main(["mcu", "monitor", "--sim", "--seconds", "1.3"]) == 0
    out = capsys.readouterr().out
    assert "ODOM" in out
    assert "BATTERY" in out
    assert "IMU" in out
    assert "%)" in out
    assert "errors none" in out
    assert "total: frames" in out


def test_monitor_every_frame(capsys: pytest.CaptureFixture[str]):
    assert main(["mcu", "monitor", "--sim", "--seconds", "0.3", "--frames"]) == 0
    out = capsys.readouterr().out
    assert "ODOM     x=" in out
    assert "IMU      gx=" in out


def test_monitor_on_a_silent_port_says_so(capsys: pytest.CaptureFixture[str]):
    pty = PtyMcu(FirmwareModel())  # never pumped: nothing is sent
    try:
        assert main(["mcu", "monitor", "--port", pty.port_name, "--seconds", "0.2"]) == 2
    finally:
        pty.close()
    assert "no frames decoded" in capsys.readouterr().err


def test_missing_port_is_one_clear_line(capsys: pytest.CaptureFixture[str]):
    assert main(["mcu", "monitor", "--port", "/nonexistent/ttyACM9"]) == 2
    err = capsys.readouterr().err
    assert "cannot open MCU port /nonexistent/ttyACM9" in err
    assert "Traceback" not in err


def test_auto_detect_takes_the_first_ttyacm(tmp_path):
    pattern = str(tmp_path / "ttyACM*")
    with pytest.raises(DeviceNotConnectedError, match="no MCU serial port found"):
        find_port("auto", pattern)
    for name in ("ttyACM1", "ttyACM0"):
        (tmp_path / name).touch()
    assert find_port("auto", pattern) == str(tmp_path / "ttyACM0")
    assert find_port("/dev/ttyUSB3", pattern) == "/dev/ttyUSB3"
    with pytest.raises(DeviceNotConnectedError, match="cannot open MCU port"):
        open_port(str(tmp_path / "ttyACM0"), 115200)  # a plain file is no serial port


def test_pty_unplug_removes_the_link_and_replug_restores_it():
    pty = PtyMcu(FirmwareModel())
    try:
        first = pty.slave_name
        assert os.path.realpath(pty.port_name) == first
        pty.unplug()
        assert not os.path.exists(pty.port_name)
        assert not pty.plugged
        pty.pump(0.1)  # harmless while unplugged
        pty.replug()
        assert os.path.exists(pty.port_name)
        assert pty.plugged
        assert os.path.realpath(pty.port_name) == pty.slave_name
    finally:
        pty.close()
    assert not os.path.exists(os.path.dirname(pty.port_name))


def test_pty_writes_once_per_odom_period_and_loses_no_frame():
    """The pty gets one write per 20 ms (ODOM + BATTERY + IMU frames), not one per 10 ms
    step: each write wakes the bridge's RX thread (a GIL hand-over on the sim's hot path)."""
    from sage_robot.hardware.mcu import protocol as proto

    fw = FirmwareModel()
    pty = PtyMcu(fw)
    try:
        port = open_port(pty.port_name, 115200)
        for k in range(1, 101):  # 1 s of 10 ms steps
            pty.pump(k * 0.01)
        assert pty.writes == fw.frames_sent["ODOM"] == 50
        decoder = proto.Decoder()
        frames: list[proto.Frame] = []
        deadline = time.monotonic() + 2.0
        while sum(fw.frames_sent.values()) - len(frames) > 1 and time.monotonic() < deadline:
            frames += decoder.feed(port.read(port.in_waiting or 1))
        counts = {k: sum(f.kind.name == k for f in frames) for k in ("ODOM", "BATTERY", "IMU")}
        assert counts == {"ODOM": 50, "BATTERY": 50, "IMU": 100}  # the last IMU waits <= 10 ms
        port.close()
    finally:
        pty.close()
