"""Per firmware dialect (``sage bench mcu``): what of SAGE's commands reaches the motors,
and how fast a stop gets there when the command is lost.

- ``commands``: ``--dialect-commands`` random commands (v, w uniform in ±1 m/s, ±3 rad/s;
  every 20th a float whose bytes hold 0x78) written by the dialect's writer into that
  dialect's firmware receiver (the models' own: byte-hunting for ``documented``, fixed
  9-byte blocks for ``seed-2025``), over a line that loses or repeats one byte after a
  frame with probability ``--glitch`` (seeded). ``applied`` / ``sent``, and ``wild``: an
  applied command SAGE never sent (must be 0). The bridge's realignment (it needs the
  robot's odometry) is not in this stream; ``applied_clean`` is the same without glitches.
- ``old_frames_into_seed_firmware``: the framed commands SAGE used to write, fed to the
  seed-2025 receiver: what the robot's owners measured (none applied, some wild).
- ``silence_to_zero_s`` / ``kill_to_zero_s``: the real bridge (wall clock) over a pty to the
  dialect's model: a publisher at 10 Hz goes silent / SAGE's process is killed with
  SIGKILL under the supervisor; seconds from the last command to a stop received.
"""

from __future__ import annotations

import argparse
import signal
import struct
from typing import Any

import numpy as np

SEED = 0
MAX_V_MPS, MAX_W_RADPS = 1.0, 3.0
HEADER_EVERY = 20  # every this many commands, one whose float bytes hold 0x78


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--dialect-commands", type=int, default=2000, help="random commands per dialect")
    p.add_argument("--glitch", type=float, default=0.01, help="chance of a lost/extra byte after a frame")


def _receiver(name: str) -> Any:
    from sage_robot.sim.firmware.blockrx import BlockReceiver
    from sage_robot.sim.firmware.rx import CommandReceiver

    if name == "seed-2025":
        rx = BlockReceiver()
        return lambda data: rx.feed(data)
    rx_doc = CommandReceiver()
    return lambda data: rx_doc.feed(data, 0.0)


def _commands(rng: np.random.Generator, n: int, with_headers: bool = True) -> list[tuple[float, float]]:
    out = []
    for i in range(n):
        v, w = float(rng.uniform(-MAX_V_MPS, MAX_V_MPS)), float(rng.uniform(-MAX_W_RADPS, MAX_W_RADPS))
        if with_headers and i % HEADER_EVERY == 0:  # a float with 0x78 in its low byte
            v = struct.unpack("<f", bytes((0x78,)) + struct.pack("<f", v)[1:])[0]
        out.append((v, w))
    return out


def _stream_case(speech: Any, receiver_name: str, commands: list[tuple[float, float]], glitch: float,
                 rng: np.random.Generator) -> dict[str, Any]:
    """``speech``: the dialect whose writer SAGE uses; wild = applied but never written."""
    feed = _receiver(receiver_name)
    writer = speech.command
    sent = np.array([speech.command_values(writer(v, w)) for v, w in commands])
    applied: list[tuple[float, float]] = []
    glitches = 0
    for v, w in commands:
        data = writer(v, w)
        if rng.random() < glitch:
            glitches += 1
            data = data[:-1] if rng.random() < 0.5 else data + data[-1:]  # a byte lost / repeated
        applied.extend(feed(data))
    wild = 0
    for v, w in applied:  # exact float32 values: a command SAGE wrote comes back bit for bit
        if not np.any((sent[:, 0] == v) & (sent[:, 1] == w)):
            wild += 1
    return {"sent": len(commands), "applied": len(applied), "wild": wild, "glitches": glitches}


async def _timing(dialect: str) -> dict[str, Any]:
    from sage_robot.bench.safety import _navigator_silent, _process_fault
    from sage_robot.bench.safety_rig import RobotSide

    robot = RobotSide(dialect)
    robot.start()
    try:
        silent = await _navigator_silent(robot, 0.3)
        await robot.reset()
        killed = await _process_fault(robot, 0.3, True, signal.SIGKILL)
        await robot.reset()
    finally:
        robot.close()
    return {"silence_to_zero_s": silent["zero_on_wire_s"], "kill_to_zero_s": killed["zero_on_wire_s"],
            "kill_to_rest_s": killed["at_rest_s"]}


async def run_dialects(args: argparse.Namespace) -> dict[str, Any]:
    from sage_robot.hardware.mcu.dialects import DIALECTS, DOCUMENTED

    out: dict[str, Any] = {}
    for name, speech in DIALECTS.items():
        commands = _commands(np.random.default_rng(SEED), args.dialect_commands)
        glitched = _stream_case(speech, name, commands, args.glitch, np.random.default_rng(SEED + 1))
        clean = _stream_case(speech, name, commands, 0.0, np.random.default_rng(SEED + 1))
        out[name] = {
            "commands": glitched,
            "applied_clean": clean["applied"],
            "wild_clean": clean["wild"],
            **await _timing(name),
        }
    commands = _commands(np.random.default_rng(SEED), args.dialect_commands, with_headers=False)
    out["old_frames_into_seed_firmware"] = _stream_case(
        DOCUMENTED, "seed-2025", commands, 0.0, np.random.default_rng(SEED + 1)
    )
    return out
