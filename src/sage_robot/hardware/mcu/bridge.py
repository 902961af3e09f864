"""SerialBridgeNode: the bus <-> STM32 link (the seed's serial_bridge.py).

- Speaks the firmware's dialect (``mcu.firmware``: ``seed-2025`` or ``documented``,
  :mod:`sage_robot.hardware.mcu.dialects`). A stop is always written so that the firmware
  applies it whatever its alignment; with a block-aligned firmware (seed-2025) an
  :class:`AlignmentWatch` compares commands with odometry and realigns it by single
  filler bytes when commands stop taking effect; a boot banner is logged and evented.

- ``/cmd_vel`` -> CMD frames, clamped to the profile's limits (never reverse unless the
  profile allows it); a standing non-zero command is re-sent at ``mcu.resend_hz`` so the
  MCU's 550 ms watchdog never trips mid-motion; a stop is sent on zero, on shutdown, and
  when the command grows older than ``mcu.cmd_timeout_s`` (0.25 s by default: the bridge's
  own dead-man, looked at every :data:`CMD_TIMEOUT_CHECK_S` by a watch of its own, so it
  does not depend on the web deadman or the navigator being alive). At rest (a stop
  commanded, odometry still) the watch looks every :data:`IDLE_CHECK_S` and a command wakes
  it at once: an idle robot's motion process wakes 20 times a second, not 100.
- With a firmware that reports no battery (seed-2025) ``/battery_state`` carries NaN
  (unknown) once a second, so every page, the brain and the watchdog say "unknown".
- A dedicated RX thread decodes ODOM -> ``/odom``, BATTERY -> ``/battery_state`` (the
  voltage averaged over ``BATTERY_SMOOTHING_TAU_S`` on the node's clock, so the motors'
  load sag does not swing the percentage; published at most every
  :data:`BATTERY_PUBLISH_PERIOD_S`, however often the firmware reports it) and
  (``mcu.imu_enabled``) IMU -> ``/imu/data`` after the start-up bias calibration,
  publishing through ``bus.publish_threadsafe``. On a simulated clock that follows another
  process's (process groups) there is no thread: the loop waits on the port (``add_reader``)
  and decodes and stamps the bytes itself, on the clock it follows. On a lockstep simulated
  clock there is no thread either: the loop reads the port every :data:`SIM_RX_POLL_S`.
- Run by the supervisor (:mod:`sage_robot.app.supervisor`, ``sage up``'s default), it
  writes a heartbeat byte every ``HEARTBEAT_PERIOD_S`` to the pipe the supervisor gave it;
  when the heartbeat stops (frozen process, stalled loop) the supervisor stops the motors.
- The port is ``ctx.resources[PORT_RESOURCE]`` when a simulator put one there, else
  ``mcu.port`` ('auto' finds /dev/ttyACM*). Losing it (USB unplug) logs one line,
  publishes an ERROR DiagnosticStatus on ``/mcu/status`` while down and reopens every
  ``mcu.reconnect_s`` until it is back.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import os
import threading
from collections import Counter
from collections.abc import Callable
from typing import Any

from sage_robot.core import topics
from sage_robot.core.clock import TIME_EPS_S
from sage_robot.core.errors import DeviceNotConnectedError
from sage_robot.core.msgs import (
    BatteryState,
    DiagnosticStatus,
    Event,
    Imu,
    Level,
    Odometry,
    PowerStatus,
    Twist,
)
from sage_robot.core.node import Node
from sage_robot.core.resources import ResourceKey
from sage_robot.hardware.mcu import protocol as proto
from sage_robot.hardware.mcu.alignment import ODOM_STILL_MPS, ODOM_STILL_RADPS, AlignmentWatch
from sage_robot.hardware.mcu.convert import (
    ImuCalibrator,
    VoltageSmoother,
    battery_from,
    clamp_command,
    odometry_from,
)
from sage_robot.hardware.mcu.dialects import BannerWatch, dialect
from sage_robot.hardware.mcu.port import HEARTBEAT_PERIOD_S, find_port, heartbeat_fd, open_port

PORT_RESOURCE = ResourceKey("mcu_port", str)  # a port path set by the simulator (or a bench)


class TxCount:
    """Bytes this process's bridge has written to its port, ever. A simulated MCU in the same
    process reads it to know how many bytes are on their way to it: the kernel hands pty
    bytes over in a worker of its own, so "readable now" alone would depend on the load."""

    __slots__ = ("total",)

    def __init__(self) -> None:
        self.total = 0


TX_COUNT_RESOURCE = ResourceKey("mcu_tx_bytes", TxCount)
# Set where the simulated MCU's pty is read by a bridge in another process (process groups):
# that bridge reads whenever it runs, so the simulator cannot step in lockstep with it.
PORT_READ_ELSEWHERE = ResourceKey("mcu_port_read_elsewhere", bool)
CMD_TIMEOUT_CHECK_S = 0.01  # while commanded or moving: how often the command age is checked (clock s)
IDLE_CHECK_S = 0.05  # at rest: how often the link and the firmware are looked at (clock s)
# At rest in followed simulated time, the watch's turn rides on a read of the port once this
# long has passed since the last (clock s): the firmware's bytes come every 20 ms, so its own
# IDLE_CHECK_S timer only fires when they stop, and the process wakes 20 times a second less.
IDLE_TURN_ON_READ_S = 0.03
TIMEOUT_LOG_EVERY_S = 10.0  # a command timeout is logged at most this often (clock s)
STATUS_PERIOD_S = 1.0  # /mcu/status and the frame-rate window (clock s)
SIM_RX_POLL_S = 0.005  # on a simulated clock the port is read in the loop this often (clock s)
BATTERY_PUBLISH_PERIOD_S = 1.0  # /battery_state at most this often (clock s; a 30 s average); firmware: 50 Hz
RX_JOIN_TIMEOUT_S = 1.0  # the RX thread wakes every READ_TIMEOUT_S, so this is ample
FROM_MCU = frozenset(t.code for t in proto.FRAME_TYPES.values() if t.direction is proto.Direction.FROM_MCU)


class SerialBridgeNode(Node):
    name = "serial_bridge"

    async def setup(self) -> None:
        self.mcu = self.settings.mcu
        self.dialect = dialect(self.mcu.firmware)
        self.banner = BannerWatch()
        self._rebooted = threading.Event()  # the RX thread saw a boot banner
        self._odom_twist: tuple[float, float] | None = None  # latest ODOM (v, w), from the RX thread
        self._realign_pending = False
        robot = self.settings.robot
        self._limits = (robot.max_linear_mps, robot.max_angular_radps, robot.allow_reverse)
        self.align = AlignmentWatch(limits=self._limits) if self.dialect.block_aligned else None
        self.decoder = proto.Decoder(accept=FROM_MCU)
        self._port: Any = None
        self.port_path = ""
        self.tx_count = self.ctx.resources.setdefault(TX_COUNT_RESOURCE, TxCount())
        self._rx_thread: threading.Thread | None = None
        self._reader_fd: int | None = None  # followed simulated time: the loop reads the port
        self._rx_stop = threading.Event()
        self._lost = threading.Event()
        self._lost_reason = ""
        self._next_open = self.clock.now()
        self._down_logged = False
        self._down_reason = "not opened yet"
        self.command: tuple[float, float] = (0.0, 0.0)
        self._command_t = self._written_at = self.clock.now()  # the last command, the last write
        self.counters: Counter[str] = Counter()
        self._rates: dict[str, float] = {}
        self._rate_base: tuple[float, dict[str, int]] = (self.clock.now(), {})
        self.battery_smoother = VoltageSmoother()
        self._battery_published_at = -math.inf  # clock s of the last /battery_state
        self.battery_raw_v: float | None = None
        self.calibrator = ImuCalibrator(self.mcu.imu_calibration_s) if self.mcu.imu_enabled else None
        self._moved_logged_at: float | None = None
        self._timeout_logged_at = -TIMEOUT_LOG_EVERY_S
        self._logged_at: dict[str, float] = {}
        self.bus.declare(topics.ODOM, Odometry)
        self.bus.declare(topics.BATTERY, BatteryState)
        self.bus.declare(topics.IMU, Imu)
        self.bus.declare(topics.MCU_STATUS, DiagnosticStatus)
        self._wake = asyncio.Event()  # a command for the watch that looks less often at rest
        self._watch_idle = False  # the watch waits for _wake (at rest)
        self._turn_at = self.clock.now()  # the watch's last turn
        self.subscribe(topics.CMD_VEL, Twist, self._on_cmd_vel)
        self.every(STATUS_PERIOD_S, self._publish_status, "serial_bridge.status")
        self._beat_fd = heartbeat_fd()
        if self._beat_fd is not None:  # run by the supervisor: tell it this bridge is alive
            os.set_blocking(self._beat_fd, False)
        # The link, the command's age and re-sending, the firmware's alignment and the
        # heartbeat are one watch of their own (also with cmd_timeout_s = 0).
        self.spawn(self._watch_loop(), "serial_bridge.watch")
        if self.clock.is_lockstep:  # no RX thread: reads at fixed simulated times (deterministic)
            self.every(SIM_RX_POLL_S, self._poll_rx, "serial_bridge.rx")

    async def teardown(self) -> None:
        if getattr(self, "_port", None) is None:
            return  # setup never opened anything
        self._write(0.0, 0.0)  # the robot must not keep the last command
        self._close_port()

    # ------------------------------------------------------------ commands
    def _on_cmd_vel(self, msg: Twist) -> None:
        v, w = clamp_command(msg.linear_x, msg.angular_z, *self._limits)
        if (v, w) != (msg.linear_x, msg.angular_z):
            self.counters["cmd_clamped"] += 1
        if self.align is not None and (v, w) != self.command:
            self.align.reset()
        self.command, self._command_t = (v, w), self.clock.now()
        self._write(v, w)
        self._wake.set()

    async def _watch_loop(self) -> None:
        """Every CMD_TIMEOUT_CHECK_S while the robot is commanded or moving, else every
        IDLE_CHECK_S or at the next command: the link, the command's age, the re-send of a
        standing command at ``mcu.resend_hz``, the firmware, the supervisor's heartbeat."""
        beat_at = self.clock.now()
        while True:
            now = self._turn_at = self.clock.now()
            try:
                self._watch_turn(now)
            except Exception as exc:  # the watch stops stale commands: no bug in a job may end it
                self.counters["watch_errors"] += 1
                if self._log_due("watch_error"):
                    self.log.error("serial bridge watch failed; going on", error=repr(exc))
            if self._beat_fd is not None and now >= beat_at - TIME_EPS_S:
                self._beat()
                beat_at = max(beat_at + HEARTBEAT_PERIOD_S, now)
            if self._busy():
                await self.clock.sleep(CMD_TIMEOUT_CHECK_S)
                continue
            self._wake.clear()
            self._watch_idle = True
            try:
                with contextlib.suppress(asyncio.TimeoutError):
                    await self.clock.wait_for(self._wake.wait(), IDLE_CHECK_S)
            finally:
                self._watch_idle = False

    def _watch_turn(self, now: float) -> None:
        self._link_step()
        stopped = self._check_timeout()
        resend_s = 1.0 / self.mcu.resend_hz
        if not stopped and self.command != (0.0, 0.0) and now - self._written_at >= resend_s - TIME_EPS_S:
            self._write(*self.command)

    def _busy(self) -> bool:
        """Commanded, moving, or realigning the firmware: watched closely."""
        odom = self._odom_twist
        moving = odom is not None and (abs(odom[0]) > ODOM_STILL_MPS or abs(odom[1]) > ODOM_STILL_RADPS)
        return self.command != (0.0, 0.0) or moving or self._realign_pending

    def _check_timeout(self) -> bool:
        """Stop a command nobody repeats any more; True when it did. Also watches the
        firmware's alignment (seed-2025) and its reboots."""
        self._watch_firmware()
        timeout = self.mcu.cmd_timeout_s
        if self.command == (0.0, 0.0) or timeout <= 0 or self.clock.now() - self._command_t <= timeout:
            return False
        now = self.clock.now()
        if now - self._timeout_logged_at >= TIMEOUT_LOG_EVERY_S:  # the counter has them all
            self._timeout_logged_at = now
            self.log.warning("no /cmd_vel for a while: stopping", timeout_s=timeout,
                             times=self.counters["cmd_timeouts"] + 1)
        self.counters["cmd_timeouts"] += 1
        self.command = (0.0, 0.0)
        self._write(0.0, 0.0)
        return True

    def _watch_firmware(self) -> None:
        if self._rebooted.is_set():
            self._rebooted.clear()
            self.counters["mcu_reboots"] += 1
            self.log.warning("the MCU rebooted (boot banner)", banner=self.banner.last)
            self._event("mcu_rebooted", f"the MCU rebooted ({self.banner.last})")
            if self.align is not None:
                self.align.reset()
        if self.align is None or self._port is None:
            return
        action = self.align.update(self.command, self._odom_twist, self.clock.now())
        if action == "step":
            self.counters["realign_bytes"] += 1
            self._realign_pending = True  # one filler byte before the next command
            self._write(*self.command)
        elif action == "stop":
            self.counters["stop_repeats"] += 1
            self._write(0.0, 0.0)
            if self.align.runaways > self.counters["runaways"]:  # a new runaway: say it once
                self.counters["runaways"] = self.align.runaways
                self.log.error("the robot moves beyond every command SAGE sends (a wild command on "
                               "the MCU): stop sent; if it keeps moving, cut the motor power")
                self._event("mcu_runaway", "the robot moves faster than commanded: stopping; "
                            "if it does not stop, use the hardware e-stop")
            elif self._log_due("stop_repeat"):
                self.log.warning("still moving after a stop: stop sent again")

    def _log_due(self, key: str) -> bool:
        """True at most every TIMEOUT_LOG_EVERY_S per key (repeated warnings)."""
        now = self.clock.now()
        if now - self._logged_at.get(key, -TIMEOUT_LOG_EVERY_S) < TIMEOUT_LOG_EVERY_S:
            return False
        self._logged_at[key] = now
        return True

    def _beat(self) -> None:
        assert self._beat_fd is not None
        # A full pipe is a live parent that is behind; a gone one can't hear.
        with contextlib.suppress(BlockingIOError, BrokenPipeError):
            os.write(self._beat_fd, b".")

    def _write(self, v: float, w: float) -> None:
        port = self._port
        if port is None:
            return
        import serial

        data = self.dialect.stop() if (v, w) == (0.0, 0.0) else self.dialect.command(v, w)
        if self._realign_pending:
            data, self._realign_pending = self.dialect.realign_step() + data, False
        try:
            self.tx_count.total += port.write(data) or 0
            self.counters["cmd_sent"] += 1
            self._written_at = self.clock.now()
        except serial.SerialTimeoutException:
            self.counters["write_timeouts"] += 1
        except (serial.SerialException, OSError) as exc:
            self._mark_lost(f"write failed: {exc}")

    # ------------------------------------------------------------ link
    def _link_step(self) -> None:
        if self._lost.is_set():
            self._on_lost()
        if self._port is None and self.clock.now() >= self._next_open:
            self._try_open()

    def _try_open(self) -> None:
        self._next_open = self.clock.now() + self.mcu.reconnect_s
        try:
            path = self.ctx.resources.get(PORT_RESOURCE) or find_port(self.mcu.port)
            port = open_port(path, self.mcu.baud)
        except DeviceNotConnectedError as exc:
            self._down_reason = str(exc)
            if not self._down_logged:
                self.log.warning("MCU not connected; retrying", reason=str(exc), every_s=self.mcu.reconnect_s)
                self._down_logged = True
                self._publish_status()
            return
        if self.counters["connects"]:
            self.counters["reconnects"] += 1
        self.counters["connects"] += 1
        self._port, self.port_path, self._down_logged = port, path, False
        self.decoder.reset()
        self._odom_twist = None
        if self.align is not None:
            self.align.reset()
        self._lost.clear()
        self._rx_stop = threading.Event()
        if self.clock.is_simulated and not self.clock.is_lockstep:
            # Time that follows another process is the loop's: bytes are decoded (stamped)
            # there, so the loop waits on the port itself (a thread would only hand them over,
            # two wake-ups per read instead of one).
            self._reader_fd = port.fileno()
            asyncio.get_running_loop().add_reader(self._reader_fd, self._on_readable, port)
        elif not self.clock.is_lockstep:  # a real port: read whatever the loop is doing
            args = (port, self._rx_stop, self._on_bytes)
            self._rx_thread = threading.Thread(
                target=self._rx_loop, args=args, name="serial_bridge.rx", daemon=True
            )
            self._rx_thread.start()
        self.log.info("MCU link up", port=path, baud=self.mcu.baud)
        if self.counters["reconnects"]:
            self._event("mcu_reconnected", f"MCU link back on {path}")
        self._write(*self.command)
        self._publish_status()

    def _mark_lost(self, reason: str) -> None:
        if not self._lost.is_set():
            self._lost_reason = reason
            self._lost.set()

    def _on_lost(self) -> None:
        reason = self._lost_reason
        self._close_port()
        self._lost.clear()
        self._down_reason = f"link lost: {reason}"
        self._down_logged = True
        self._next_open = self.clock.now() + self.mcu.reconnect_s
        self.counters["disconnects"] += 1
        self.log.warning(
            "MCU link lost; reconnecting by itself",
            port=self.port_path,
            reason=reason,
            every_s=self.mcu.reconnect_s,
        )
        self._event("mcu_disconnected", f"MCU link lost: {reason}")
        self._publish_status()

    def _event(self, kind: str, message: str) -> None:
        self.bus.publish(topics.EVENTS, Event(self.clock.now(), self.name, kind, message))

    def _close_port(self) -> None:
        self._stop_reader()
        self._rx_stop.set()
        if self._rx_thread is not None:
            self._rx_thread.join(RX_JOIN_TIMEOUT_S)
            self._rx_thread = None
        if self._port is not None:
            try:
                self._port.close()
            except Exception as exc:  # closing a vanished device may fail; it is gone anyway
                self.log.debug("closing the MCU port failed", error=str(exc))
            self._port = None

    # ------------------------------------------------------------ RX thread
    def _rx_loop(self, port: Any, stop: threading.Event, deliver: Callable[[bytes], None]) -> None:
        try:
            while not stop.is_set():
                data = port.read(port.in_waiting or 1)
                if data:
                    waiting = port.in_waiting  # what came with that first byte: one hand-over, not two
                    deliver(data + port.read(waiting) if waiting else data)
        except Exception as exc:  # SerialException/OSError on unplug; anything else too
            if not stop.is_set():
                self._mark_lost(f"{type(exc).__name__}: {exc}")

    def _on_readable(self, port: Any) -> None:
        """Followed simulated time: the port is readable (or hung up), read on the loop."""
        try:
            data = port.read(port.in_waiting or 1)
        except Exception as exc:  # SerialException/OSError: the simulator's pty went away
            self._stop_reader()
            self._mark_lost(f"{type(exc).__name__}: {exc}")
            return
        if data:
            self._on_bytes(data)
        if self._watch_idle and self.clock.now() - self._turn_at >= IDLE_TURN_ON_READ_S - TIME_EPS_S:
            self._wake.set()  # the watch's turn now: the process is awake anyway

    def _stop_reader(self) -> None:
        if self._reader_fd is not None:
            with contextlib.suppress(RuntimeError, ValueError, OSError):  # the loop or fd closed first
                asyncio.get_running_loop().remove_reader(self._reader_fd)
            self._reader_fd = None

    def _poll_rx(self) -> None:
        """Lockstep simulated clock: read what the port holds, in the loop (the simulator's pty makes
        every byte of a step readable before the step ends)."""
        port = self._port
        if port is None or self._lost.is_set():
            return
        try:
            waiting = port.in_waiting
            if waiting:
                self._on_bytes(port.read(waiting))
        except Exception as exc:  # SerialException/OSError on unplug
            self._mark_lost(f"{type(exc).__name__}: {exc}")

    def _on_bytes(self, data: bytes) -> None:
        if self.banner.feed(data):
            self._rebooted.set()
        for frame in self.decoder.feed(data):
            self._on_frame(frame)

    def _on_frame(self, frame: proto.Frame) -> None:
        now = self.clock.now()
        kind = frame.kind
        if kind is proto.ODOM:
            self._odom_twist = (frame.values[3], frame.values[4])
            self.bus.publish_threadsafe(topics.ODOM, odometry_from(frame.values, now))
        elif kind is proto.BATTERY:
            self.battery_raw_v = frame.values[0]
            smooth = self.battery_smoother.update(frame.values[0], now)
            if now - self._battery_published_at >= BATTERY_PUBLISH_PERIOD_S - 1e-9:
                self._battery_published_at = now
                msg = battery_from(smooth, self.settings.battery.discharge_curve, now)
                self.bus.publish_threadsafe(topics.BATTERY, msg)
        elif kind is proto.IMU and self.calibrator is not None:
            self._on_imu(frame.values, now)

    def _on_imu(self, values: tuple[float, ...], now: float) -> None:
        cal = self.calibrator
        assert cal is not None
        if cal.bias is None:
            result = cal.add(now, values[:3], values[3:])
            if result.moved and (
                self._moved_logged_at is None or now - self._moved_logged_at >= cal.window_s
            ):
                self._moved_logged_at = now
                self.log.warning(
                    "robot moved during IMU calibration: keep it still; retrying",
                    window_s=cal.window_s,
                    retries=cal.retries,
                )
            if result.done:
                bias = cal.bias or (0.0, 0.0, 0.0)
                self.log.info("IMU calibrated", bias_radps=[round(b, 5) for b in bias])
            return
        self.bus.publish_threadsafe(topics.IMU, cal.correct(values, now))

    # ------------------------------------------------------------ health
    @property
    def connected(self) -> bool:
        return self._port is not None and not self._lost.is_set()

    def _update_rates(self) -> None:
        now = self.clock.now()
        t0, base = self._rate_base
        frames = dict(self.decoder.stats.frames)
        if now > t0:
            self._rates = {k: round((frames.get(k, 0) - base.get(k, 0)) / (now - t0), 1) for k in frames}
        self._rate_base = (now, frames)

    def _publish_status(self) -> None:
        if not self.dialect.has_battery:  # the firmware reports no battery: say "unknown", never 0 %
            self.bus.publish(topics.BATTERY, BatteryState(self.clock.now(), math.nan, math.nan,
                                                          PowerStatus.UNKNOWN))
        self._update_rates()
        st = self.decoder.stats
        values = {
            "port": self.port_path,
            "frames_per_s": str(self._rates),
            "bytes_dropped": str(st.bytes_dropped),
            "errors": str(dict(st.errors)),
            "cmd_sent": str(self.counters["cmd_sent"]),
        }
        if self.connected:
            status = DiagnosticStatus("mcu", Level.OK, f"connected to {self.port_path}", values)
        else:
            status = DiagnosticStatus("mcu", Level.ERROR, f"MCU disconnected: {self._down_reason}", values)
        self.bus.publish(topics.MCU_STATUS, status)

    def stats(self) -> dict[str, Any]:
        st = self.decoder.stats
        return {
            "connected": self.connected,
            "port": self.port_path,
            "frames": dict(st.frames),
            "frames_per_s": dict(self._rates),
            "bytes_in": st.bytes_in,
            "bytes_dropped": st.bytes_dropped,
            "errors": dict(st.errors),
            "command": list(self.command),
            "imu_calibrated": bool(self.calibrator and self.calibrator.bias is not None),
            "battery_raw_v": None if self.battery_raw_v is None else round(self.battery_raw_v, 3),
            "firmware": self.dialect.name,
            "banner": self.banner.last,
            **dict(self.counters),
        }
