"""The firmware model behind a pseudo-terminal, so the real serial bridge talks to it
unchanged, and McuSimNode, which runs it on the simulator's clock.

``PtyMcu.port_name`` is a stable symlink that points at the pty's slave (like
/dev/serial/by-id on the robot): :meth:`PtyMcu.unplug` closes the pty and removes the
link, as a USB unplug removes /dev/ttyACM0; :meth:`PtyMcu.replug` opens a new pty and puts
the link back, so a bridge configured with the link finds the device again.

The link lives in ``mcu-<pid>-<random>/`` under a private per-user directory
(``$XDG_RUNTIME_DIR/sage``, else ``<tmp>/sage-<uid>``, mode 0700). :meth:`PtyMcu.close`
removes it; a process killed with SIGKILL cannot, so every new :class:`PtyMcu` first
removes the directories of this user whose owner PID is no longer alive.
"""

from __future__ import annotations

import array
import contextlib
import fcntl
import logging
import os
import re
import shutil
import stat
import tempfile
import termios
import time
import tty
from pathlib import Path
from typing import Any

import numpy as np

from sage_robot.core.clock import SimClock
from sage_robot.core.node import SIM_STEP_HOOKS, Node
from sage_robot.core.resources import ResourceKey
from sage_robot.hardware.mcu.bridge import PORT_READ_ELSEWHERE, PORT_RESOURCE, TX_COUNT_RESOURCE, TxCount
from sage_robot.sim.firmware import FirmwareModel, SimFirmware, make_firmware
from sage_robot.sim.flat_floor import FlatFloor, SimBody

BAUD = termios.B115200
READ_CHUNK = 4096  # bytes read from the master per call
FLUSH_BYTES = 256  # write at once when this much waits (ODOM off, e.g. a test's own frames)
LOCKSTEP_WAIT_S = 1.0  # lockstep: longest wait for the kernel to hand written bytes over (wall s)
LOCKSTEP_POLL_S = 0.0001  # ... looking this often (wall s)
LINK_NAME = "ttySIM0"
# The body the firmware model moves, when a simulated world provides one (the world's)
SIM_BODY: ResourceKey[SimBody] = ResourceKey("sim_body")
MCU_SIM_RESOURCE: ResourceKey[McuSimNode] = ResourceKey("mcu_sim")  # this node (tests, the world)
RUNTIME_SUBDIR = "sage"  # under $XDG_RUNTIME_DIR
LINK_DIR_PREFIX = "mcu-"  # mcu-<owner pid>-<random>: one per PtyMcu
_LINK_DIR = re.compile(rf"^{LINK_DIR_PREFIX}(\d+)-")
PRIVATE_MODE = 0o700
TRACK_MISMATCH_M = 1e-6  # firmware vs body track width difference worth a warning (m)

_log = logging.getLogger("sage.sim.mcu_pty")


def runtime_dir() -> Path | None:
    """This user's private directory for pty links, created 0700 when missing; None when
    no safe one can be had (it exists but is not a directory of ours that only we can use)."""
    xdg = os.environ.get("XDG_RUNTIME_DIR", "")
    base = Path(xdg) / RUNTIME_SUBDIR if xdg and os.path.isdir(xdg) else (
        Path(tempfile.gettempdir()) / f"sage-{os.getuid()}"
    )
    try:
        base.mkdir(mode=PRIVATE_MODE, exist_ok=True)
        st = os.lstat(base)
    except OSError as exc:
        _log.warning("no runtime directory %s: %s", base, exc)
        return None
    if not stat.S_ISDIR(st.st_mode) or st.st_uid != os.getuid() or st.st_mode & 0o077:
        _log.warning("runtime directory %s is not a private directory of this user; not used", base)
        return None
    return base


def pid_alive(pid: int) -> bool:
    """True when a process with this PID exists (ours or another user's)."""
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # it exists, it is someone else's
        return True
    return True


def remove_stale_links(base: Path) -> list[Path]:
    """Remove ``mcu-<pid>-*`` directories in ``base`` that belong to this user and whose
    PID is not alive (left by a process killed with SIGKILL). Returns what was removed."""
    removed: list[Path] = []
    try:
        entries = list(os.scandir(base))
    except OSError:
        return removed
    for entry in entries:
        m = _LINK_DIR.match(entry.name)
        if m is None or not entry.is_dir(follow_symlinks=False):
            continue
        try:
            if entry.stat(follow_symlinks=False).st_uid != os.getuid():
                continue
        except OSError:  # gone in between
            continue
        if pid_alive(int(m.group(1))):
            continue
        shutil.rmtree(entry.path, ignore_errors=True)  # holds only our symlink; links are not followed
        removed.append(Path(entry.path))
    if removed:
        _log.info("removed %d stale pty link dir(s) in %s", len(removed), base)
    return removed


class PtyMcu:
    """A pty pair with the firmware model on the master side. ``base``: where the link's
    directory goes (default :func:`runtime_dir`; stale ones there are removed first)."""

    def __init__(
        self,
        firmware: SimFirmware,
        base: Path | None = None,
        lockstep: bool = False,
        tx: TxCount | None = None,
    ) -> None:
        self.firmware = firmware
        # lockstep (a simulated clock): each write is readable on the Jetson side before pump()
        # returns, so the bridge reads it at the same simulated time on every run; and every
        # byte the bridge wrote before a pump (``tx``, its running count) is read by that pump.
        self.lockstep = lockstep
        self.tx = tx
        self._rx_total = 0  # bytes read from the Jetson side, in TxCount's reckoning
        base = base if base is not None else runtime_dir()
        if base is not None:
            remove_stale_links(base)
            self._dir = tempfile.mkdtemp(prefix=f"{LINK_DIR_PREFIX}{os.getpid()}-", dir=base)
        else:  # no private runtime dir: a fresh private temp dir (no sweep possible)
            self._dir = tempfile.mkdtemp(prefix=f"sage-{LINK_DIR_PREFIX}{os.getpid()}-")
        self.port_name = os.path.join(self._dir, LINK_NAME)
        self.master_fd = -1
        self._slave_fd = -1
        self.slave_name = ""
        self.bytes_dropped = 0  # bytes the firmware sent while nobody read them
        self.writes = 0  # os.write calls toward the Jetson
        self.bytes_written = 0  # ... and the bytes they wrote
        self.lockstep_timeouts = 0  # lockstep waits that ran out (each held the simulator LOCKSTEP_WAIT_S)
        self._pending = bytearray()  # frames produced, written with the next ODOM
        self._open()

    def _open(self) -> None:
        master, slave = os.openpty()
        tty.setraw(slave)
        attrs = termios.tcgetattr(slave)
        attrs[4] = attrs[5] = BAUD  # ispeed, ospeed
        termios.tcsetattr(slave, termios.TCSANOW, attrs)
        os.set_blocking(master, False)
        self.master_fd, self._slave_fd = master, slave
        self.slave_name = os.ttyname(slave)
        self._rx_total = self.tx.total if self.tx is not None else 0  # earlier bytes were not for this pty
        tmp = self.port_name + ".new"
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        os.symlink(self.slave_name, tmp)
        os.replace(tmp, self.port_name)

    @property
    def plugged(self) -> bool:
        return self.master_fd >= 0

    def pump(self, now: float) -> None:
        """Non-blocking: Jetson bytes -> firmware; the firmware's due frames -> Jetson."""
        if not self.plugged:
            return
        tx = self.tx
        on_the_way = tx.total - self._rx_total if self.lockstep and tx is not None else 0
        if tx is not None and on_the_way > 0 and not self._wait_readable(on_the_way, self.master_fd):
            self._rx_total = tx.total  # lost on the way (a write that failed half-way)
            self.lockstep_timeouts += 1
        while True:
            try:
                data = os.read(self.master_fd, READ_CHUNK)
            except (BlockingIOError, OSError):  # nothing waiting (EAGAIN) or no reader (EIO)
                break
            if not data:
                break
            self._rx_total += len(data)
            self.firmware.receive(data)
        fw = self.firmware
        odom_before = fw.frames_sent["ODOM"]
        self._pending += fw.transmit(now)
        # One write per ODOM period (20 ms: ODOM + BATTERY + the IMU frames since the last),
        # not one per step: each write wakes the bridge's RX thread, and that GIL hand-over
        # cost more than the firmware model itself. The 10 ms an IMU frame may wait is what
        # ~115 bytes take on the real 115200-baud wire anyway.
        if self._pending and (fw.frames_sent["ODOM"] != odom_before or len(self._pending) >= FLUSH_BYTES):
            out, self._pending = bytes(self._pending), bytearray()
            before = self._readable() if self.lockstep else 0
            try:
                written = os.write(self.master_fd, out)
            except (BlockingIOError, OSError):  # nobody reads: the buffer is full
                written = 0
            if self.lockstep and written and not self._wait_readable(before + written):
                self.lockstep_timeouts += 1
            self.bytes_dropped += len(out) - written
            self.bytes_written += written
            self.writes += 1

    def _readable(self, fd: int | None = None) -> int:
        """Bytes waiting to be read on ``fd`` (FIONREAD; default the Jetson side of the pty)."""
        buf = array.array("i", [0])
        try:
            fcntl.ioctl(self._slave_fd if fd is None else fd, termios.FIONREAD, buf, True)
        except OSError:
            return 0
        return int(buf[0])

    def _wait_readable(self, count: int, fd: int | None = None) -> bool:
        """The kernel hands pty bytes over in a worker of its own: wait (bounded) until
        ``count`` bytes are readable on ``fd`` (default the Jetson side), so that a read in this
        simulated step finds them all. False when they did not come in time."""
        deadline = time.monotonic() + LOCKSTEP_WAIT_S
        while self._readable(fd) < count:
            if time.monotonic() >= deadline:
                return False
            time.sleep(LOCKSTEP_POLL_S)
        return True

    def inject(self, data: bytes) -> None:
        """Write raw bytes toward the Jetson (tests: corrupt the line)."""
        if self.plugged:
            os.write(self.master_fd, data)

    def unplug(self) -> None:
        """Close the pty and remove the link: the bridge's port vanishes."""
        if not self.plugged:
            return
        self._pending.clear()  # frames in flight are lost with the device
        with contextlib.suppress(FileNotFoundError):
            os.unlink(self.port_name)
        for fd in (self.master_fd, self._slave_fd):
            with contextlib.suppress(OSError):
                os.close(fd)
        self.master_fd = self._slave_fd = -1

    def replug(self) -> None:
        """A new pty behind the same link."""
        if not self.plugged:
            self._open()

    def close(self) -> None:
        self.unplug()
        shutil.rmtree(self._dir, ignore_errors=True)


class McuSimNode(Node):
    """The simulated MCU: firmware model + pty + a body, stepped before each clock step.

    The model is the dialect ``mcu.firmware`` names (``sim/firmware/dialects.py``).

    Puts the pty's path in ``ctx.resources[PORT_RESOURCE]`` for the serial bridge. The body
    is ``ctx.resources[SIM_BODY]`` when a world provides one (any :class:`SimBody`), else a
    :class:`FlatFloor` of its own.
    """

    name = "mcu_sim"

    async def setup(self) -> None:

        robot = self.settings.robot
        rng = np.random.default_rng(self.settings.sim.seed)
        dialect = self.settings.mcu.firmware
        self.firmware = make_firmware(dialect, robot.track_width_m, rng)
        fw_track = self.firmware.params.track_width_m
        if abs(fw_track - robot.track_width_m) > TRACK_MISMATCH_M:
            self.log.warning(
                "the firmware's track differs from the body's: turns come out scaled",
                firmware=dialect, firmware_track_m=fw_track, body_track_m=robot.track_width_m,
            )
        self.floor = FlatFloor(robot.track_width_m)
        tx = self.ctx.resources.setdefault(TX_COUNT_RESOURCE, TxCount())
        # Lockstep needs the bridge in this process: one in another process reads whenever it
        # runs, and waiting for its bytes to be readable here would hold the simulator up.
        elsewhere = self.ctx.resources.get(PORT_READ_ELSEWHERE, False)
        self.pty = PtyMcu(self.firmware, lockstep=self.clock.is_lockstep and not elsewhere, tx=tx)
        self.ctx.resources[PORT_RESOURCE] = self.pty.port_name
        self.ctx.resources[MCU_SIM_RESOURCE] = self
        self._hooks = self.ctx.resources.setdefault(SIM_STEP_HOOKS, [])
        self._hooks.append(self.physics_step)
        self.log.info("simulated MCU ready", port=self.pty.port_name, pty=self.pty.slave_name)

    @property
    def body(self) -> SimBody:
        body = self.ctx.resources.get(SIM_BODY)
        return body if body is not None else self.floor

    def physics_step(self, dt: float) -> None:
        """One simulator step of ``dt`` s ending at clock time now + dt."""
        t = self.clock.now() + dt
        fw = self.firmware
        wheels = fw.control_step(dt, t)
        v, w = self.body.step(dt, wheels)
        fw.sense(dt, v, w)
        self.pty.pump(t)
        if isinstance(self.clock, SimClock):  # nothing commanded, nothing moving: it may wake less
            self.clock.idle = fw.stopped and fw.last_command == (0.0, 0.0)

    async def teardown(self) -> None:
        if self.physics_step in getattr(self, "_hooks", []):
            self._hooks.remove(self.physics_step)
        if self.ctx.resources.get(MCU_SIM_RESOURCE) is self:
            self.ctx.resources.pop(MCU_SIM_RESOURCE)
            self.ctx.resources.pop(PORT_RESOURCE)
        if hasattr(self, "pty"):
            self.pty.close()

    def stats(self) -> dict[str, Any]:
        fw = self.firmware
        return {
            "port": self.pty.port_name,
            "frames_sent": dict(fw.frames_sent),
            "commands_received": fw.rx.frames,
            "rx_errors": dict(fw.rx.errors),
            "watchdog_trips": fw.watchdog_trips,
            "pwm_us": list(fw.pwm_us),
            "battery_v": round(fw.battery_voltage, 3),
            "lockstep": self.pty.lockstep,
            "lockstep_timeouts": self.pty.lockstep_timeouts,
        }


class RealTimeMcu:
    """The firmware model on a flat floor, stepped in wall-clock time by a thread.

    For tools that run without the simulator's clock (``sage mcu monitor --sim``,
    ``sage bench mcu``). Use as a context manager; ``port_name`` is the pty link.
    """

    def __init__(self, firmware: SimFirmware | None = None, step_s: float = 0.01) -> None:
        import threading

        self.firmware: SimFirmware = firmware or FirmwareModel()
        self.floor = FlatFloor(self.firmware.params.track_width_m)
        self.pty = PtyMcu(self.firmware)
        self.port_name = self.pty.port_name
        self.step_s = step_s
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="mcu-sim", daemon=True)
        self._thread.start()

    def _loop(self) -> None:
        import time

        t0 = time.monotonic()
        k = 0
        while not self._stop.is_set():
            k += 1
            t = k * self.step_s
            wheels = self.firmware.control_step(self.step_s, t)
            v, w = self.floor.step(self.step_s, wheels)
            self.firmware.sense(self.step_s, v, w)
            self.pty.pump(t)
            delay = t0 + t - time.monotonic()
            if delay > 0:
                self._stop.wait(delay)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(1.0)
        self.pty.close()

    def __enter__(self) -> RealTimeMcu:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
