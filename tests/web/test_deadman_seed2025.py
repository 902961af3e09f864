"""The web deadman and e-stop against the seed-2025 firmware model (no watchdog on the MCU):
the stop reaches the firmware over the real pty in its dialect. (The same tests against the
documented firmware: test_protocol.py.)"""

from __future__ import annotations

import json
import time
from collections.abc import Iterator
from typing import Any

import pytest

from ..support.waits import wait_until
from .conftest import SimRobot, sim_robot
from .wsclient import teleop_ws


@pytest.fixture(scope="module")
def robot(tmp_path_factory: pytest.TempPathFactory) -> Iterator[SimRobot]:
    with sim_robot(tmp_path_factory, "web-seed", mcu={"firmware": "seed-2025"}) as sim:
        yield sim


def _firmware(robot: Any) -> Any:
    return robot.launcher.nodes["mcu_sim"].firmware


def _record_applied(robot: Any) -> list[tuple[float, float]]:
    """Every command the firmware model's block receiver applies, in order (a brief 0.3 m/s
    between a command and the deadman's stop is not missed by polling)."""
    fw = _firmware(robot)
    applied: list[tuple[float, float]] = []
    feed = fw.rx.feed

    def spy(data: bytes) -> list[tuple[float, float]]:
        out = feed(data)
        applied.extend(out)
        return out

    robot.call(lambda: setattr(fw.rx, "feed", spy))
    return applied


def _after(applied: list[tuple[float, float]], first: float, then: float) -> bool:
    """``first`` m/s was applied, and later ``then``."""
    vs = [round(v, 6) for v, _ in list(applied)]
    return first in vs and then in vs[vs.index(first):]


def test_the_seed_firmware_runs_here(robot: Any) -> None:
    assert type(_firmware(robot)).__name__ == "Seed2025Model"
    assert robot.call(lambda: robot.launcher.nodes["serial_bridge"].stats()["firmware"]) == "seed-2025"


def test_the_deadman_stop_reaches_the_seed_firmware(robot: Any, cookie: str) -> None:
    applied = _record_applied(robot)
    teleop = robot.web_node().teleop
    stops = teleop.counts["deadman_stops"]
    with teleop_ws(robot, cookie) as ws:
        ws.send(json.dumps({"type": "control", "x": 0.3, "z": 0.0}))  # then the operator goes silent
        wait_until(lambda: teleop.counts["deadman_stops"] > stops, "the deadman fired")
        wait_until(lambda: _after(applied, 0.3, 0.0), "0.3 m/s reached the firmware, then the deadman's stop")
    assert _firmware(robot).last_command == (0.0, 0.0)


def test_the_estop_reaches_the_seed_firmware(robot: Any, cookie: str) -> None:
    applied = _record_applied(robot)
    fw = _firmware(robot)
    teleop = robot.web_node().teleop
    with teleop_ws(robot, cookie) as ws:
        for _ in range(3):  # the page repeats a held command every 0.1 s
            ws.send(json.dumps({"type": "control", "x": 0.3, "z": 0.0}))
            time.sleep(0.1)  # the operator's cadence, not a wait for anything
        ws.send(json.dumps({"type": "estop", "engaged": True}))
        wait_until(lambda: _after(applied, 0.3, 0.0), "driving, then the e-stop's stop reached the firmware")
        wait_until(lambda: fw.last_command == (0.0, 0.0), "the firmware holds the stop")
    robot.run(teleop.set_estop(False, "test"))
