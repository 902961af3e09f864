"""The port's last word: a small parent process that runs SAGE and stops the motors after it.

Whatever ends the robot's process — a clean exit, an exception, ``kill -9``, the kernel's
out-of-memory killer — this parent is still there: it waits for the child and then writes
stop commands to the MCU port at once (:data:`STOP_REPEATS` frames :data:`STOP_GAP_S`
apart). With firmware that has no command watchdog this is the only thing between a dead
process and a robot that keeps driving its last command. The parent imports no ML code,
holds the port open from the start (no lock, so the child's serial bridge opens it as
usual) and forwards SIGINT/SIGTERM to the child.

It also watches the child's serial bridge while it runs: the bridge writes a heartbeat byte
to a pipe (``SAGE_HEARTBEAT_FD``) every 50 ms (``hardware.mcu.port.HEARTBEAT_PERIOD_S``); when none has come
for :data:`HEARTBEAT_TIMEOUT_S` (the process is frozen, its event loop stalled, the bridge
died inside a live process) the parent writes the stop itself, and again every
:data:`STALL_REPEAT_S` while the silence lasts. A bridge that comes back simply goes on.

``sage up`` runs itself under it by default (``--no-supervisor`` to skip it, e.g. when
systemd's ``ExecStopPost`` does the same job). Alone::

    python -m sage_robot.app.supervisor --port /dev/ttyACM0 -- sage up --no-supervisor
"""

from __future__ import annotations

import argparse
import contextlib
import os
import select
import signal
import subprocess
import sys
import time
from types import FrameType
from typing import Any

from sage_robot.hardware.mcu.dialects import dialect
from sage_robot.hardware.mcu.port import HEARTBEAT_FD_ENV, find_port

SUPERVISED_ENV = "SAGE_SUPERVISED"  # set in the child: it must not start a supervisor itself
HEARTBEAT_TIMEOUT_S = 0.2  # no heartbeat this long: the parent stops the motors (s)
STALL_REPEAT_S = 0.1  # and repeats the stop this often while the silence lasts (s)
STOP_REPEATS = 3  # stop frames written after the child ends (one may land mid-frame)
STOP_GAP_S = 0.02  # between them (s)
DEFAULT_BAUD = 115200


def stop_frame(firmware: str = "seed-2025") -> bytes:
    """The bytes that stop the robot in ``firmware``'s dialect, whatever its alignment."""
    return dialect(firmware).stop()


class LastWord:
    """The MCU port, held open by the parent to write the stop when the child is gone."""

    def __init__(self, configured: str, baud: int = DEFAULT_BAUD, firmware: str = "seed-2025") -> None:
        self.configured, self.baud, self.firmware = configured, baud, firmware
        self.port: Any = None
        self.path = ""

    def open(self) -> bool:
        try:
            import serial

            self.path = find_port(self.configured)
            self.port = serial.Serial(self.path, self.baud, timeout=0, write_timeout=0.2, exclusive=False)
        except Exception as exc:  # not plugged in yet: try again when it matters
            print(f"sage supervisor: MCU port not open yet ({exc}); will retry at the end", file=sys.stderr)
            self.port = None
        return self.port is not None

    def say_stop(self) -> bool:
        """Write the stop frames; True when they went out."""
        if self.port is None and not self.open():
            return False
        frame = stop_frame(self.firmware)
        try:
            for i in range(STOP_REPEATS):
                self.port.write(frame)
                self.port.flush()
                if i + 1 < STOP_REPEATS:
                    time.sleep(STOP_GAP_S)
        except Exception as exc:
            print(f"sage supervisor: could not write the stop to {self.path}: {exc}", file=sys.stderr)
            return False
        return True

    def close(self) -> None:
        if self.port is not None:
            with contextlib.suppress(Exception):
                self.port.close()
            self.port = None


def supervise(cmd: list[str], port: str, baud: int = DEFAULT_BAUD, announce: bool = False,
              firmware: str = "seed-2025") -> int:
    """Run ``cmd`` as the child and stop the motors when it ends or stalls; its exit status."""
    last = LastWord(port, baud, firmware)
    last.open()
    beat_r, beat_w = os.pipe()
    env = dict(os.environ, **{SUPERVISED_ENV: "1", HEARTBEAT_FD_ENV: str(beat_w)})
    child = subprocess.Popen(cmd, env=env, pass_fds=(beat_w,))
    os.close(beat_w)
    if announce:
        print(f"child {child.pid}", flush=True)

    def forward(signum: int, _frame: FrameType | None) -> None:
        with contextlib.suppress(ProcessLookupError):
            child.send_signal(signum)

    previous = {s: signal.signal(s, forward) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        watch_heartbeat(beat_r, child, last)
        rc = child.wait()
    finally:
        os.close(beat_r)
        stopped = last.say_stop()
        last.close()
        for s, handler in previous.items():
            signal.signal(s, handler)
    how = f"killed by signal {-rc}" if rc < 0 else f"exit status {rc}"
    said = "stop sent" if stopped else "no port to stop"
    print(f"sage supervisor: the robot process ended ({how}); {said}", file=sys.stderr)
    return 128 - rc if rc < 0 else rc


def watch_heartbeat(fd: int, child: subprocess.Popen[bytes], last: LastWord) -> None:
    """Until the child ends: stop the motors whenever its bridge's heartbeat goes quiet.
    Before the first beat (start-up, no bridge in this process) nothing is watched."""
    seen, quiet_since, last_stop = False, time.monotonic(), 0.0
    while child.poll() is None:
        ready, _, _ = select.select([fd], [], [], STALL_REPEAT_S / 2)
        now = time.monotonic()
        if ready:
            if not os.read(fd, 4096):
                return  # every writer closed it: the child is ending
            seen, quiet_since = True, now
            continue
        if seen and now - quiet_since > HEARTBEAT_TIMEOUT_S and now - last_stop >= STALL_REPEAT_S:
            if last_stop < quiet_since:
                print("sage supervisor: the serial bridge went quiet; stopping the motors", file=sys.stderr)
            last.say_stop()
            last_stop = now


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m sage_robot.app.supervisor",
                                description=(__doc__ or "").splitlines()[0])
    p.add_argument("--port", required=True, help="the MCU serial port ('auto' finds /dev/ttyACM*)")
    p.add_argument("--baud", type=int, default=DEFAULT_BAUD)
    p.add_argument("--announce", action="store_true", help="print 'child PID' on stdout")
    p.add_argument("--firmware", default="seed-2025", choices=["seed-2025", "documented"],
                   help="the MCU firmware's dialect (mcu.firmware)")
    p.add_argument("cmd", nargs=argparse.REMAINDER, help="-- then the command to run")
    args = p.parse_args(argv)
    cmd = args.cmd[1:] if args.cmd[:1] == ["--"] else args.cmd
    if not cmd:
        p.error("give the command to run after --")
    return supervise(cmd, args.port, args.baud, args.announce, args.firmware)


if __name__ == "__main__":
    sys.exit(main())
