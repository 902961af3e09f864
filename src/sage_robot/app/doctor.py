"""`sage doctor`'s checks: each says what it found and, when something is wrong, the fix.

They work on a machine with no robot attached (everything "absent", clearly) and against
emulated devices (the firmware model behind a pty, the RPLIDAR emulator).
"""

from __future__ import annotations

import glob
import importlib.util
import os
import platform
import shutil
import socket
import sys
import time
import urllib.error
import urllib.request
from collections.abc import Callable
from dataclasses import dataclass

from sage_robot.core.config import Settings
from sage_robot.core.errors import DeviceNotConnectedError

MCU_LISTEN_S = 1.0  # how long to count MCU frames
LIDAR_TIMEOUT_S = 3.0
MIN_FREE_DISK_BYTES = 1 << 30  # 1 GiB
HTTP_TIMEOUT_S = 3.0

NMCLI_HELP = (
    "the robot is not on a network. Reconnect Wi-Fi (seed section 1): "
    '`nmcli device wifi list` then `nmcli device wifi connect "SSID" password "PASSWORD"`; '
    "if SSH is impossible, attach a monitor and keyboard and run the same commands"
)


@dataclass
class Check:
    name: str
    ok: bool
    detail: str
    fix: str = ""
    essential: bool = True

    @property
    def mark(self) -> str:
        return "ok" if self.ok else ("FAIL" if self.essential else "warn")


def check_python(settings: Settings) -> Check:
    ok = sys.version_info >= (3, 10)
    return Check("python", ok, platform.python_version(), "install Python 3.10 or newer")


def check_mcu(settings: Settings) -> Check:
    from sage_robot.hardware.mcu.dialects import BannerWatch, guess
    from sage_robot.hardware.mcu.port import find_port, open_port
    from sage_robot.hardware.mcu.protocol import Decoder

    try:
        path = find_port(settings.mcu.port)
        port = open_port(path, settings.mcu.baud)
    except DeviceNotConnectedError as exc:
        return Check("mcu", False, f"absent: {exc}", "plug in the STM32 (USB-C); check `ls /dev/ttyACM*`")
    decoder, banner = Decoder(), BannerWatch()
    frames = 0
    t0 = time.monotonic()
    try:
        while time.monotonic() - t0 < MCU_LISTEN_S:
            data = port.read(256)
            banner.feed(data)
            frames += len(decoder.feed(data))
    finally:
        port.close()
    rate = frames / MCU_LISTEN_S
    if not frames:
        return Check(
            "mcu",
            False,
            f"{path} is open but silent",
            "the STM32 may not be running: its green LED (PA5) should blink; replug the cable",
        )
    counts = ", ".join(f"{k} {v / MCU_LISTEN_S:.0f}/s" for k, v in sorted(decoder.stats.frames.items()))
    errors = sum(decoder.stats.errors.values())
    seems, configured = guess(dict(decoder.stats.frames), banner.banners), settings.mcu.firmware
    detail = f"{path}: {rate:.0f} frames/s ({counts}); {errors} bad frames; firmware seems {seems}"
    if seems not in ("unknown", configured):
        return Check("mcu", False, f"{detail}, but the profile says mcu.firmware: {configured}",
                     f"set mcu.firmware: {seems} in the profile (docs/mcu.md): the robot ignores "
                     "commands in the other dialect")
    battery = "" if seems != "seed-2025" else " (no battery frames: the battery shows as unknown)"
    return Check("mcu", True, detail + battery)


def check_lidar(settings: Settings) -> Check:
    from sage_robot.hardware.rplidar.driver import RplidarDriver

    cfg = settings.lidar
    if not os.path.exists(cfg.port):
        return Check(
            "lidar",
            False,
            f"absent: {cfg.port} not found",
            "plug in the RPLIDAR (USB adapter); check `ls /dev/ttyUSB*` or set lidar.port",
            essential=False,
        )
    try:
        with RplidarDriver(cfg.port, cfg.baud) as lidar:
            info = lidar.info()
            health, code = lidar.health()
            t0 = time.monotonic()
            samples = 0
            for rev in lidar.revolutions():
                samples = len(rev)
                break
            spin_s = time.monotonic() - t0
            lidar.stop()
    except Exception as exc:
        return Check(
            "lidar", False, f"{cfg.port}: {exc}", "power-cycle the lidar; check the cable", essential=False
        )
    ok = health != "error" and samples > 0 and spin_s < LIDAR_TIMEOUT_S
    return Check(
        "lidar",
        ok,
        f"{cfg.port}: model {info.model:#x}, health {health} ({code}), spinning, "
        f"{samples} samples/revolution",
        "the lidar reports an error: power-cycle it",
        essential=False,
    )


def check_camera(settings: Settings) -> Check:
    dev = settings.camera.device
    found = sorted(glob.glob("/dev/video*"))
    if dev.isdigit() or os.path.exists(dev):
        return Check("camera", True, f"{dev} present ({len(found)} video devices)", essential=False)
    return Check(
        "camera",
        False,
        f"absent: {dev} not found ({', '.join(found) or 'no /dev/video*'})",
        "plug in the USB camera or set camera.device",
        essential=False,
    )


def check_audio(settings: Settings) -> Check:
    if importlib.util.find_spec("sounddevice") is None:
        return Check(
            "audio", False, "sounddevice not installed", "pip install 'sage-robot[voice]'", essential=False
        )
    try:
        import sounddevice as sd

        devices = sd.query_devices()
    except Exception as exc:  # PortAudio missing or no sound server
        return Check(
            "audio",
            False,
            f"no audio devices: {exc}",
            "install libportaudio2; on the robot start PulseAudio: `pulseaudio --start`",
            essential=False,
        )
    ins = [d["name"] for d in devices if d.get("max_input_channels", 0) > 0]
    outs = [d["name"] for d in devices if d.get("max_output_channels", 0) > 0]
    ok = bool(ins and outs)
    return Check(
        "audio",
        ok,
        f"{len(ins)} inputs, {len(outs)} outputs",
        "connect the XVF3800 mic array and the speaker",
        essential=False,
    )


def check_models(settings: Settings) -> Check:
    wanted = {
        "speech to text (faster-whisper)": "faster_whisper",
        "text to speech (piper)": "piper",
        "wake word (openwakeword)": "openwakeword",
        "embeddings (knowledge base)": "sage_robot.kb",
    }
    missing = [label for label, mod in wanted.items() if importlib.util.find_spec(mod.split(".")[0]) is None]
    if missing:
        return Check(
            "models",
            False,
            "missing: " + ", ".join(missing),
            "pip install 'sage-robot[all]'",
            essential=False,
        )
    problem = _wake_files_problem(settings)
    if problem:
        return Check("models", False, problem, "fix voice.wake_models / voice.wake_heads in the profile",
                     essential=False)  # fmt: skip
    return Check("models", True, "speech, wake word and embedding packages installed", essential=False)


def _wake_files_problem(settings: Settings) -> str:
    """The profile's wake models and heads, resolved: '' or what is wrong."""
    from sage_robot.core.errors import ConfigError
    from sage_robot.voice.wake import resolve_wake_model
    from sage_robot.voice.wake_head import load_head

    try:
        for spec in settings.voice.wake_models:
            resolve_wake_model(spec)
        for head in settings.voice.wake_heads.values():
            load_head(head)
    except ConfigError as exc:
        return str(exc)
    return ""


def _port_free(host: str, port: int) -> bool:
    with socket.socket() as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((host, port))
            return True
        except OSError:
            return False


def check_ports(settings: Settings) -> Check:
    wanted = {"web": settings.web.port, "foxglove": settings.ops.foxglove_port}
    busy = [f"{name} {port}" for name, port in wanted.items() if port and not _port_free("0.0.0.0", port)]
    if busy:
        return Check(
            "ports",
            False,
            "in use: " + ", ".join(busy),
            "another SAGE may be running (`sage status`); stop it or change web.port / ops.foxglove_port",
            essential=False,
        )
    return Check("ports", True, ", ".join(f"{n} {p} free" for n, p in wanted.items()), essential=False)


def check_network(settings: Settings) -> Check:
    import psutil

    addrs = []
    for iface, entries in psutil.net_if_addrs().items():
        for a in entries:
            if a.family == socket.AF_INET and not a.address.startswith("127."):
                addrs.append(f"{iface} {a.address}")
    if not addrs:
        return Check("network", False, "no IPv4 address besides loopback", NMCLI_HELP, essential=False)
    return Check("network", True, "; ".join(addrs), essential=False)


def check_disk(settings: Settings) -> Check:
    from sage_robot.core.paths import state_dir

    free = shutil.disk_usage(state_dir()).free
    ok = free >= MIN_FREE_DISK_BYTES
    return Check(
        "disk",
        ok,
        f"{free / 2**30:.1f} GiB free in {state_dir()}",
        "free some space (recordings in the state directory can go)",
        essential=False,
    )


def check_kb(settings: Settings) -> Check:
    if importlib.util.find_spec("sage_robot.kb.service") is None:
        return Check(
            "kb", False, "knowledge base module missing", "pip install 'sage-robot[all]'", essential=False
        )
    backend = settings.kb.backend
    if backend == "postgres" and settings.kb.dsn:
        return _http_or_dsn("kb", settings.kb.dsn)
    return Check("kb", True, f"{backend} store (opened at start-up)", essential=False)


def _http_or_dsn(name: str, dsn: str) -> Check:
    host = dsn.split("@")[-1].split("/")[0]
    hostname, _, port = host.partition(":")
    try:
        with socket.create_connection((hostname or "127.0.0.1", int(port or 5432)), HTTP_TIMEOUT_S):
            return Check(name, True, f"PostgreSQL reachable at {host}", essential=False)
    except OSError as exc:
        return Check(
            name,
            False,
            f"PostgreSQL at {host} unreachable: {exc}",
            "start the database or fix kb.dsn",
            essential=False,
        )


def check_llm(settings: Settings) -> Check:
    url = settings.llm.base_url
    if not url:
        return Check("llm", True, "none configured: the offline brain answers", essential=False)
    try:
        with urllib.request.urlopen(url.rstrip("/") + "/models", timeout=HTTP_TIMEOUT_S) as resp:
            return Check("llm", True, f"{url} answers ({resp.status})", essential=False)
    except urllib.error.HTTPError as exc:  # 401 still means the endpoint is up
        return Check("llm", exc.code < 500, f"{url} answers {exc.code}", "check the API key", essential=False)
    except (urllib.error.URLError, OSError) as exc:
        return Check(
            "llm",
            False,
            f"{url} unreachable: {exc}",
            "check the network and llm.base_url; the offline brain answers meanwhile",
            essential=False,
        )


CHECKS: list[Callable[[Settings], Check]] = [
    check_python,
    check_mcu,
    check_lidar,
    check_camera,
    check_audio,
    check_models,
    check_ports,
    check_network,
    check_disk,
    check_kb,
    check_llm,
]


def run_checks(settings: Settings) -> list[Check]:
    out = []
    for check in CHECKS:
        try:
            out.append(check(settings))
        except Exception as exc:  # a broken check is a finding, not a crash
            out.append(
                Check(check.__name__.removeprefix("check_"), False, f"check failed: {exc}", essential=False)
            )
    return out
