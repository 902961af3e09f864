"""The supervisor has the port's last word: SAGE's process killed (SIGKILL) or frozen
(SIGSTOP) mid-drive, and the firmware model behind a real pty still receives a stop.

The firmware model is pumped on the wall clock in this process; SAGE's side (the real
serial bridge and a 0.5 m/s publisher) runs in a child process under
``python -m sage_robot.app.supervisor``. Bounds are generous (a loaded CI machine); the
numbers themselves come from ``sage bench safety``.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator

import pytest

from sage_robot.bench.safety_rig import CHILD
from sage_robot.sim.firmware import FirmwareModel, Seed2025Model
from sage_robot.sim.mcu_pty import PtyMcu

from ..support.waits import wait_until

PUMP_S = 0.005  # the firmware model's step here (s)
DRIVING_WITHIN_S = 20.0  # the child must be driving within this (wall s)
STOP_WITHIN_S = 2.0  # and the firmware must have a stop this soon after the fault (wall s)
SPEED_MPS = 0.5


class Firmware(threading.Thread):
    """The firmware model behind a pty, pumped in real time; remembers every command."""

    def __init__(self, dialect: str) -> None:
        super().__init__(daemon=True, name="test-firmware")
        self.model = Seed2025Model() if dialect == "seed-2025" else FirmwareModel()
        self.pty = PtyMcu(self.model)
        self.done = threading.Event()
        self.dialect = dialect
        self.t0 = time.monotonic()

    def run(self) -> None:
        k = 0
        while not self.done.is_set():
            k += 1
            self.pty.pump(k * PUMP_S)
            time.sleep(max(0.0, self.t0 + k * PUMP_S - time.monotonic()))

    def close(self) -> None:
        self.done.set()
        self.join(2.0)
        self.pty.close()


@pytest.fixture(params=["seed-2025", "documented"])
def firmware(request: pytest.FixtureRequest) -> Iterator[Firmware]:
    fw = Firmware(request.param)
    fw.start()
    try:
        yield fw
    finally:
        fw.close()


def _start_supervised(port: str, dialect: str) -> tuple[subprocess.Popen[str], int]:
    cmd = [sys.executable, "-m", "sage_robot.app.supervisor", "--announce", "--firmware", dialect,
           "--port", port, "--", sys.executable, "-c", CHILD, port, str(SPEED_MPS), dialect]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    first = proc.stdout.readline()
    assert first.startswith("child "), f"the supervisor announces its child, got {first!r}"
    return proc, int(first.split()[1])


@pytest.mark.parametrize("fault", [signal.SIGKILL, signal.SIGSTOP], ids=["killed", "frozen"])
def test_the_supervisor_stops_the_motors_when_sage_dies_or_freezes(firmware: Firmware, fault: int) -> None:
    proc, child = _start_supervised(firmware.pty.port_name, firmware.dialect)
    try:
        wait_until(lambda: firmware.model.last_command[0] == pytest.approx(SPEED_MPS),
                   "the supervised bridge to drive", DRIVING_WITHIN_S, poll=0.002)
        frames = firmware.model.rx.frames  # a few more commands: a standing drive, not a start-up blip
        wait_until(lambda: firmware.model.rx.frames >= frames + 3, "three more drive commands",
                   DRIVING_WITHIN_S, poll=0.002)
        os.kill(child, fault)
        # the safety bound (wall clock, 10x the supervisor's heartbeat timeout)
        wait_until(lambda: firmware.model.last_command == (0.0, 0.0), "the firmware to receive a stop",
                   STOP_WITHIN_S, poll=0.002)
        if fault == signal.SIGKILL:
            assert proc.wait(10.0) == 128 + signal.SIGKILL  # the supervisor reports how the child ended
            assert proc.stderr is not None
            assert "killed by signal 9" in proc.stderr.read()
    finally:
        for pid in (child, proc.pid):
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        proc.wait(10.0)


def test_without_a_command_the_supervisor_refuses_clearly() -> None:
    out = subprocess.run([sys.executable, "-m", "sage_robot.app.supervisor", "--port", "/dev/null"],
                         capture_output=True, text=True, timeout=30)
    assert out.returncode == 2
    assert "give the command to run" in out.stderr
