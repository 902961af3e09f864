"""`sage mcu monitor` and `sage mcu drive`: the first tools to plug into the real robot.

``monitor`` prints the decoded frames, their rates and the link's error counts once a
second (``--frames``: every frame), and which firmware dialect the MCU seems to speak (a
``WHO_AM_I`` boot banner, ODOM without BATTERY frames: seed-2025; BATTERY frames:
documented), with a warning when that disagrees with the profile's ``mcu.firmware``.
``drive`` is a bounded test drive in the profile's dialect (``--firmware`` overrides it):
the command is clamped to the profile's limits (never reverse), re-sent at
``mcu.resend_hz``, and a stop is sent at the end and on Ctrl-C. ``--sim`` runs either
against the firmware model behind a pseudo-terminal instead of a serial port.
"""

from __future__ import annotations

import argparse
import contextlib
import time
from collections.abc import Iterator
from typing import Any

from sage_robot.core.errors import SageError

MAX_DRIVE_S = 10.0  # longest test drive (s): a typo must not send the robot down the hall
REPORT_PERIOD_S = 1.0  # monitor summary period (s)
DRIVE_REPORT_S = 0.5  # drive progress period (s)
STOP_REPEATS = 3  # stop frames sent at the end (a lost byte must not leave it moving)


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser("mcu", help="talk to the STM32 motor controller (monitor, test drive)")
    p.set_defaults(help_parser=p)
    msub = p.add_subparsers(dest="mcu_command", metavar="ACTION")

    m = msub.add_parser("monitor", help="live decoded frames, rates and error counts")
    _port_args(m)
    m.add_argument("--seconds", type=float, help="stop after this long (default: Ctrl-C)")
    m.add_argument("--frames", action="store_true", help="print every frame, not a summary")
    m.set_defaults(func=run_monitor)

    d = msub.add_parser("drive", help="a short, bounded test drive (stops at the end)")
    _port_args(d)
    d.add_argument("--v", type=float, default=0.2, help="forward speed (m/s, >= 0)")
    d.add_argument("--w", type=float, default=0.0, help="turn rate (rad/s, + = left)")
    d.add_argument("--seconds", type=float, default=2.0, help=f"duration (s, at most {MAX_DRIVE_S:g})")
    d.set_defaults(func=run_drive)


def _port_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--port", help="serial device (default: mcu.port of the profile, 'auto')")
    p.add_argument("--firmware", choices=["seed-2025", "documented"],
                   help="the firmware's dialect (default: mcu.firmware of the profile)")
    p.add_argument("--sim", action="store_true", help="use the firmware model on a pty")


@contextlib.contextmanager
def _open_link(args: argparse.Namespace) -> Iterator[tuple[Any, Any, str]]:
    """(serial port, settings, label); with --sim, a firmware model runs behind a pty."""
    from sage_robot.core.config import load_profile
    from sage_robot.hardware.mcu.port import find_port, open_port

    overrides = {"mcu": {"firmware": args.firmware}} if args.firmware else None
    settings = load_profile(args.profile, overrides)
    sim = None
    if args.sim:
        import numpy as np

        from sage_robot.sim.firmware import make_firmware
        from sage_robot.sim.mcu_pty import RealTimeMcu

        model = make_firmware(settings.mcu.firmware, settings.robot.track_width_m,
                              np.random.default_rng(settings.sim.seed))
        sim = RealTimeMcu(model)
        path = sim.port_name
    else:
        path = find_port(args.port or settings.mcu.port)
    try:
        port = open_port(path, settings.mcu.baud)
        try:
            yield port, settings, ("firmware model on " + path) if sim else path
        finally:
            port.close()
    finally:
        if sim is not None:
            sim.close()


def _read(port: Any) -> bytes:
    import serial

    try:
        return bytes(port.read(port.in_waiting or 1))
    except (serial.SerialException, OSError) as exc:
        raise SageError(f"the MCU port went away: {exc}") from None


def _fmt(values: dict[str, float]) -> str:
    return " ".join(f"{k}={v:+.3f}" for k, v in values.items())


def run_monitor(args: argparse.Namespace) -> int:
    from sage_robot.hardware.mcu import protocol as proto
    from sage_robot.hardware.mcu.convert import battery_percentage
    from sage_robot.hardware.mcu.dialects import BannerWatch

    with _open_link(args) as (port, settings, label):
        print(f"monitoring {label} at {settings.mcu.baud} baud; Ctrl-C to stop")
        decoder = proto.Decoder()
        banner = BannerWatch()
        latest: dict[str, proto.Frame] = {}
        t0 = last = time.monotonic()
        counts_at_last: dict[str, int] = {}
        try:
            while args.seconds is None or time.monotonic() - t0 < args.seconds:
                data = _read(port)
                if banner.feed(data):
                    print(f"{time.monotonic() - t0:8.3f} boot banner: {banner.last} (the MCU (re)started)")
                for frame in decoder.feed(data):
                    latest[frame.kind.name] = frame
                    if args.frames:
                        print(f"{time.monotonic() - t0:8.3f} {frame.kind.name:<8} {_fmt(frame.as_dict())}")
                now = time.monotonic()
                if now - last >= REPORT_PERIOD_S and not args.frames:
                    _summary(decoder, latest, counts_at_last, now - last, settings, battery_percentage)
                    counts_at_last, last = dict(decoder.stats.frames), now
        except KeyboardInterrupt:
            pass
        st = decoder.stats
        print(
            f"total: frames {dict(st.frames)}, bytes {st.bytes_in}, dropped {st.bytes_dropped}, "
            f"errors {dict(st.errors) or 'none'}"
        )
        _say_dialect(dict(st.frames), banner, settings.mcu.firmware)
        if not st.frames:
            raise SageError(f"no frames decoded from {label}: wrong port, or the MCU is not running")
    return 0


def _say_dialect(frames: dict[str, int], banner: Any, configured: str) -> None:
    from sage_robot.hardware.mcu.dialects import guess

    seems = guess(frames, banner.banners)
    why = f"banner {banner.last!r}, " if banner.banners else ""
    print(f"firmware: seems to speak {seems} ({why}frames {frames or 'none'}); the profile says {configured}")
    if seems not in ("unknown", configured):
        print(f"WARNING: set mcu.firmware: {seems} in the profile (docs/mcu.md), or the robot "
              "will not accept SAGE's commands")


def _summary(
    decoder: Any, latest: dict[str, Any], before: dict[str, int], dt: float, settings: Any, pct: Any
) -> None:
    st = decoder.stats
    parts = []
    for name in ("ODOM", "BATTERY", "IMU"):
        rate = (st.frames.get(name, 0) - before.get(name, 0)) / dt
        frame = latest.get(name)
        text = _fmt(frame.as_dict()) if frame else "-"
        if name == "BATTERY" and frame:
            text += f" ({100 * pct(frame.values[0], settings.battery.discharge_curve):.0f} %)"
        parts.append(f"{name} {rate:5.1f}/s {text}")
    errors = dict(st.errors) or "none"
    print(" | ".join(parts) + f" | dropped {st.bytes_dropped} B, errors {errors}")


def run_drive(args: argparse.Namespace) -> int:
    from sage_robot.hardware.mcu import protocol as proto
    from sage_robot.hardware.mcu.convert import clamp_command
    from sage_robot.hardware.mcu.dialects import dialect

    if not 0 < args.seconds <= MAX_DRIVE_S:
        raise SageError(f"--seconds must be in (0, {MAX_DRIVE_S:g}], got {args.seconds:g}")
    with _open_link(args) as (port, settings, label):
        robot = settings.robot
        v, w = clamp_command(
            args.v, args.w, robot.max_linear_mps, robot.max_angular_radps, robot.allow_reverse
        )
        if (v, w) != (args.v, args.w):
            print(f"command clamped to the profile's limits: v={v:g} m/s, w={w:g} rad/s")
        speech = dialect(settings.mcu.firmware)
        print(f"driving v={v:g} m/s w={w:g} rad/s for {args.seconds:g} s on {label} "
              f"({speech.name} firmware); Ctrl-C stops")
        decoder = proto.Decoder()
        odom: dict[str, float] = {}
        period = 1.0 / settings.mcu.resend_hz
        stop_frame = speech.stop()  # applied whatever a block-aligned firmware's alignment
        try:
            t0 = time.monotonic()
            next_send = next_report = t0
            while (now := time.monotonic()) - t0 < args.seconds:
                if now >= next_send:
                    port.write(speech.command(v, w))
                    next_send += period
                for frame in decoder.feed(_read(port)):
                    if frame.kind is proto.ODOM:
                        odom = frame.as_dict()
                if now >= next_report and odom:
                    print(f"{now - t0:5.2f} s  {_fmt(odom)}")
                    next_report += DRIVE_REPORT_S
        except KeyboardInterrupt:
            print("interrupted")
        finally:
            for _ in range(STOP_REPEATS):
                port.write(stop_frame)
            port.flush()
        print(f"stopped; last odometry {_fmt(odom) if odom else 'none received'}")
    return 0
