"""The web deadman and e-stop against the seed-2025 firmware model (no watchdog on the MCU):
the stop reaches the firmware over the real pty in its dialect. (The same tests against the
documented firmware: test_protocol.py.)"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Iterator
from typing import Any

import httpx
import pytest
from websockets.sync.client import connect

from .conftest import PASSWORD, SimRobot

WAIT_S = 5.0


@pytest.fixture(scope="module")
def robot(tmp_path_factory: pytest.TempPathFactory) -> Iterator[SimRobot]:
    tmp = tmp_path_factory.mktemp("web-seed")
    old = {k: os.environ.get(k) for k in ("SAGE_OPERATOR_PASSWORD", "SAGE_STATE_DIR")}
    os.environ["SAGE_OPERATOR_PASSWORD"] = PASSWORD
    os.environ["SAGE_STATE_DIR"] = str(tmp / "state")
    sim = SimRobot(tmp, mcu={"firmware": "seed-2025"}).start()
    try:
        yield sim
    finally:
        sim.stop()
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


@pytest.fixture(scope="module")
def cookie(robot: Any) -> str:
    resp = httpx.post(f"{robot.url}/api/login", json={"password": robot.password})
    assert resp.status_code == 200
    return f"sage_session={resp.cookies['sage_session']}"


def _firmware(robot: Any) -> Any:
    return robot.launcher.nodes["mcu_sim"].firmware


def _wait(cond: Any, what: str) -> None:
    deadline = time.monotonic() + WAIT_S
    while time.monotonic() < deadline and not cond():
        time.sleep(0.005)
    assert cond(), what


def _teleop(robot: Any, cookie: str) -> Any:
    url = robot.url.replace("http://", "ws://") + "/ws/teleop"
    return connect(url, additional_headers={"Cookie": cookie}, open_timeout=WAIT_S)


def test_the_seed_firmware_runs_here(robot: Any) -> None:
    assert type(_firmware(robot)).__name__ == "Seed2025Model"
    assert robot.call(lambda: robot.launcher.nodes["serial_bridge"].stats()["firmware"]) == "seed-2025"


def test_the_deadman_stop_reaches_the_seed_firmware(robot: Any, cookie: str) -> None:
    fw = _firmware(robot)
    with _teleop(robot, cookie) as ws:
        ws.send(json.dumps({"type": "control", "x": 0.3, "z": 0.0}))
        _wait(lambda: abs(fw.last_command[0] - 0.3) < 1e-6, "the command reached the firmware")
        t_sent = time.monotonic()  # and now the operator goes silent
        _wait(lambda: fw.last_command == (0.0, 0.0), "the deadman's stop reached the firmware")
        silent = time.monotonic() - t_sent
        assert silent < 2.0, f"stopped after {silent:.2f} s"  # 0.25 s deadman; generous for CI


def test_the_estop_reaches_the_seed_firmware(robot: Any, cookie: str) -> None:
    fw = _firmware(robot)
    teleop = robot.web_node().teleop
    with _teleop(robot, cookie) as ws:
        for _ in range(5):
            ws.send(json.dumps({"type": "control", "x": 0.3, "z": 0.0}))
            time.sleep(0.1)
        _wait(lambda: abs(fw.last_command[0] - 0.3) < 1e-6, "driving")
        ws.send(json.dumps({"type": "estop", "engaged": True}))
        _wait(lambda: fw.last_command == (0.0, 0.0), "the e-stop's stop reached the firmware")
    robot.run(teleop.set_estop(False, "test"))
