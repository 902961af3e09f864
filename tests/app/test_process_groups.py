"""Process groups: the profile's grouping, and groups as real processes under one supervisor.

The supervisor's Zenoh router listens on a free loopback port and each test uses its own
robot id, so parallel runs do not hear each other. Waits are bounded; how long a restart
took is printed (measured), never asserted.
"""

from __future__ import annotations

import asyncio
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from sage_robot.app.process_groups import PROCESS_PREFIX, GroupSupervisor, plan_groups
from sage_robot.app.profiles import PROFILES
from sage_robot.core import realtime, topics
from sage_robot.core.config import load_profile, parse_profile
from sage_robot.core.config.processes import DEFAULT_GROUPS, ProcessSettings, group_of
from sage_robot.core.errors import ConfigError
from sage_robot.core.msgs import Event, Odometry
from sage_robot.core.node import NodeState
from sage_robot.core.transport.keys import ZENOH_THREADS
from tests.support.sched import fifo_permitted
from tests.support.waits import until

CLOCK_SLACK_S = 1.0  # simulated s: /clock messages in flight to the supervisor
START_S = 90.0  # bound on a group coming up (imports and Zenoh on a loaded 2-core machine)
ZENOH_RAISED_S = 10.0  # bound on Zenoh threads started late being raised (ZENOH_RERAISE_S: 1 s)

# Packages the motion process must never import (models, speech, ML runtimes).
ML_PACKAGES = {"torch", "onnxruntime", "transformers", "sentence_transformers", "faster_whisper",
               "ctranslate2", "openwakeword", "sklearn", "llama_cpp", "tokenizers", "huggingface_hub",
               "sounddevice", "webrtcvad", "fastapi", "uvicorn"}
UPPER_LAYERS = ("sage_robot.voice", "sage_robot.brain", "sage_robot.kb", "sage_robot.nav", "sage_robot.sim")


@pytest.mark.parametrize("mode", sorted(PROFILES))
def test_the_default_groups_place_every_node_of_every_mode_once(mode: str) -> None:
    nodes = [n for n, _ in PROFILES[mode]] + ["ros2_bridge"]
    groups = group_of(DEFAULT_GROUPS, nodes)
    placed = [n for members in groups.values() for n in members]
    assert sorted(placed) == sorted(nodes)
    assert groups.get("motion", []) == [n for n in nodes if n in DEFAULT_GROUPS["motion"]]


def test_a_node_in_no_group_or_in_two_is_a_one_line_error_naming_it() -> None:
    with pytest.raises(ConfigError, match=r"node 'voice' is in no process group.*processes\.groups"):
        group_of({"motion": ("serial_bridge",)}, ["serial_bridge", "voice"])
    text = "processes:\n  groups:\n    motion: [serial_bridge, web]\n    web: [web]\n"
    with pytest.raises(ConfigError) as err:
        parse_profile(text, "robot.yaml")
    assert "node 'web' is in two groups: 'motion' and 'web'" in str(err.value)
    assert "robot.yaml" in str(err.value)


def test_a_simulated_run_without_the_sim_group_is_refused(tmp_path: Path) -> None:
    settings = _settings("x", "tcp/127.0.0.1:1", {"nav": ("navigator",)})
    with pytest.raises(ConfigError, match="needs the 'sim' group"):
        plan_groups(settings, "sim", [("navigator", True)], "tcp/127.0.0.1:1", str(tmp_path))


def test_speech_and_the_brain_run_at_a_lower_cpu_priority_by_default() -> None:
    settings = load_profile(None, {})
    nodes = [(n, False) for n in ("sim_world", "mcu_sim", "serial_bridge", "voice", "brain", "kb")]
    plans = {p.name: p.argv for p in plan_groups(settings, "sim", nodes, "tcp/127.0.0.1:7447", "/tmp")}
    assert plans["voice"][plans["voice"].index("--nice") + 1] == "5"
    assert plans["brain"][plans["brain"].index("--nice") + 1] == "5"
    assert "--nice" not in plans["motion"]
    with pytest.raises(ValueError, match="nice of group 'voice'"):
        ProcessSettings(nice={"voice": 40})


def test_the_motion_process_runs_at_a_real_time_priority_by_default() -> None:
    settings = load_profile(None, {})
    nodes = [(n, False) for n in ("sim_world", "mcu_sim", "serial_bridge", "navigator", "voice")]
    plans = {p.name: p.argv for p in plan_groups(settings, "sim", nodes, "tcp/127.0.0.1:7447", "/tmp")}
    assert plans["motion"][plans["motion"].index("--realtime") + 1] == "40"
    assert [g for g, argv in plans.items() if "--realtime" in argv] == ["motion"]
    with pytest.raises(ValueError, match=r"realtime priority of group .nav.: 0 is not in 1\.\.99"):
        ProcessSettings(realtime={"nav": 0})


def test_the_motion_process_imports_no_ml_package() -> None:
    """The motion group's process as group_main builds it: its nodes' classes and its transport."""
    nodes = list(DEFAULT_GROUPS["motion"])
    code = (
        "import sys, json\n"
        "from sage_robot.app import group_main\n"
        "from sage_robot.core.transport import zenoh_bus\n"
        "from sage_robot.web import auth\n"
        f"specs = group_main.group_specs('sim', {nodes!r})\n"
        "print(json.dumps(sorted(sys.modules)))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                         check=True)
    modules = set(json.loads(out.stdout))
    assert "sage_robot.hardware.mcu.bridge" in modules
    assert "zenoh" in modules
    assert sorted(m for m in modules if m.split(".")[0] in ML_PACKAGES) == []
    assert sorted(m for m in modules if m.startswith(UPPER_LAYERS)) == []


def _settings(robot: str, endpoint: str, groups: dict[str, tuple[str, ...]]) -> Any:
    base = load_profile(None, {"bus": {"robot_id": robot, "zenoh": {"listen": [endpoint]}}})
    return base.model_copy(update={"processes": ProcessSettings(groups=groups, nice={"aux": 3})})


def test_a_killed_group_comes_back_alone_and_the_others_keep_their_pids(tmp_path: Path) -> None:
    """sim (the world, the firmware model, /clock), motion (the serial bridge on the sim's pty,
    following /clock) and aux (the battery watchdog): kill -9 aux, then motion."""
    from sage_robot.app.zenoh_hub import ZenohHub
    from tests.core.zenoh_peer import free_port, unique_robot

    robot, endpoint = unique_robot(), f"tcp/127.0.0.1:{free_port()}"
    groups = {"sim": ("sim_world", "mcu_sim"), "motion": ("serial_bridge", "heartbeat"),
              "aux": ("battery_watchdog",)}
    overrides = {"bus": {"robot_id": robot}, "sim": {"camera_hz": 0}}
    nodes = [("sim_world", True), ("mcu_sim", True), ("serial_bridge", True), ("heartbeat", False),
             ("battery_watchdog", False)]
    settings = _settings(robot, endpoint, groups)
    plans = plan_groups(settings, "sim", nodes, endpoint, str(tmp_path), None, overrides)

    async def body() -> None:
        hub = ZenohHub(endpoint, robot)
        sup = GroupSupervisor(plans, hub)
        odom: list[Odometry] = []
        events: list[Event] = []
        hub.subscribe(topics.ODOM, odom.append)
        hub.subscribe(topics.EVENTS, events.append)
        await sup.start()
        try:
            await _crash_and_recover(sup, odom, events)
        finally:
            await sup.stop()
            hub.close()
        assert all(g.state is NodeState.STOPPED for g in sup.groups.values())
        assert all(g.proc is not None and g.proc.returncode is not None for g in sup.groups.values())

    asyncio.run(body())


def _zenoh_threads(pid: int) -> set[str]:
    """How a process's Zenoh threads are scheduled (one string per policy seen)."""
    out = set()
    for tid in os.listdir(f"/proc/{pid}/task"):
        with open(f"/proc/{pid}/task/{tid}/comm") as f:
            if ZENOH_THREADS.match(f.read().strip()):
                out.add(realtime.describe(int(tid)))
    return out


async def _crash_and_recover(sup: GroupSupervisor, odom: list[Odometry], events: list[Event]) -> None:
    g = sup.groups
    await until(lambda: all(p.state is NodeState.RUNNING for p in g.values()) and odom,
                "every group running and /odom from the bridge", START_S)
    # The motion group follows the simulator's /clock: its report and the odometry are in sim time.
    await until(lambda: g["motion"].report is not None and g["motion"].report.stamp > 0.5, "motion at 0.5 s",
                START_S)
    assert sup.sim_time is not None
    report = g["motion"].report
    assert report is not None
    # Simulated seconds (not the epoch), not ahead of the simulator (give or take /clock
    # messages the supervisor has yet to take).
    assert 0.5 < report.stamp <= sup.sim_time + CLOCK_SLACK_S
    assert 0.0 < odom[-1].stamp <= sup.sim_time + CLOCK_SLACK_S
    # The bridge reads the simulator's pty from another process, whenever it runs: the
    # simulator must not wait for its bytes in lockstep (each wait held it up for 1 s).
    assert g["sim"].report is not None
    mcu = {n.name: n for n in g["sim"].report.nodes}["mcu_sim"].stats
    assert mcu["lockstep"] is False
    assert mcu["lockstep_timeouts"] == 0

    pids = {name: p.pid for name, p in g.items()}
    # processes.nice: aux yields the cores to the others (every thread it starts inherits it)
    assert os.getpriority(os.PRIO_PROCESS, pids["aux"]) == 3
    assert os.getpriority(os.PRIO_PROCESS, pids["motion"]) == 0
    # processes.realtime: motion at SCHED_FIFO 40 where the machine allows it (else it says why)
    assert realtime.describe(pids["motion"]) == ("SCHED_FIFO 40" if fifo_permitted() else "normal")
    assert realtime.describe(pids["aux"]) == "normal"
    # processes.zenoh_realtime: every group's Zenoh threads at SCHED_FIFO 10, motion's kept at 40,
    # also those Zenoh starts later (raised within ZENOH_RERAISE_S: one was once seen at normal)
    if fifo_permitted():
        want = {"sim": {"SCHED_FIFO 10"}, "motion": {"SCHED_FIFO 40"}, "aux": {"SCHED_FIFO 10"}}
    else:
        want = {"sim": {"normal"}, "motion": {"normal"}, "aux": {"normal"}}
    await until(lambda: {g: _zenoh_threads(pid) for g, pid in pids.items()} == want,
                "every group's Zenoh threads at their priority", ZENOH_RAISED_S,
                detail=lambda: {g: _zenoh_threads(pid) for g, pid in pids.items()})
    os.kill(pids["aux"], signal.SIGKILL)
    t0 = time.monotonic()
    await until(lambda: g["aux"].state is NodeState.RUNNING and g["aux"].pid != pids["aux"], "aux back",
                START_S)
    print(f"aux back in {time.monotonic() - t0:.2f} s after kill -9")
    assert {n: p.pid for n, p in g.items() if n != "aux"} == {n: pids[n] for n in pids if n != "aux"}
    assert (g["aux"].restarts, g["sim"].restarts, g["motion"].restarts) == (1, 0, 0)
    entry = {h.name: h for h in sup.health_msg().nodes}[f"{PROCESS_PREFIX}aux"]
    assert (entry.state, entry.restarts, entry.last_error) == ("running", 1, "process killed by signal 9")
    assert events == []  # aux holds no critical node: no stop

    os.kill(pids["motion"], signal.SIGKILL)  # the serial bridge's process: critical
    await until(lambda: any(e.kind == "safety_stop" and "motion" in e.message for e in events),
                "a safety stop")
    seen = len(odom)
    await until(lambda: g["motion"].state is NodeState.RUNNING and len(odom) > seen + 5,
                "motion back, odom again", START_S)
    assert g["sim"].pid == pids["sim"]
    assert g["aux"].restarts == 1


def test_sim_processes_with_a_summary_flag_is_a_one_line_error(capsys: pytest.CaptureFixture[str]) -> None:
    from sage_robot.cli.main import main

    assert main(["sim", "--processes", "--json"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "sage: error: --processes runs until Ctrl-C and prints no summary: leave it out for --json"


def test_a_group_that_keeps_dying_is_restarted_with_a_doubling_delay(tmp_path: Path) -> None:
    """A real process that exits at once: each restart waits at least twice as long as the last."""
    from sage_robot.app.process_groups import BACKOFF_INITIAL_S, GroupPlan

    class NoHub:  # nothing to report to: the group never reports, so it never counts as running
        endpoint = ""

        def __init__(self) -> None:
            self.published: list[tuple[str, Any]] = []

        def subscribe(self, topic: str, callback: Any) -> None:
            pass

        def publish(self, topic: str, msg: Any) -> None:
            self.published.append((topic, msg))

        def close(self) -> None:
            pass

    plan = GroupPlan("flaky", ["heartbeat"], True, [sys.executable, "-c", "import sys; sys.exit(3)"])
    hub = NoHub()

    async def body() -> GroupSupervisor:
        sup = GroupSupervisor([plan], hub)
        await sup.start()
        try:
            await until(lambda: len(sup.groups["flaky"].spawned) >= 4, "four starts", START_S)
        finally:
            await sup.stop()
        return sup

    sup = asyncio.run(body())
    g = sup.groups["flaky"]
    gaps = [b - a for a, b in zip(g.spawned, g.spawned[1:], strict=False)]
    assert [gap >= BACKOFF_INITIAL_S * 2**i for i, gap in enumerate(gaps[:3])] == [True, True, True], gaps
    assert g.restarts >= 3
    assert g.last_error == "process exit status 3"
    stops = [m for t, m in hub.published if t == topics.EVENTS and m.kind == "safety_stop"]
    assert len(stops) >= 3
    assert "flaky is down" in stops[0].message
    assert any(t == topics.CMD_VEL and m.linear_x == 0.0 for t, m in hub.published)
    health = {h.name: h for h in sup.health_msg().nodes}
    entry = health[f"{PROCESS_PREFIX}flaky"]
    assert (entry.state, entry.restarts, entry.last_error) == ("stopped", g.restarts, "process exit status 3")
    assert health["heartbeat"].state == "stopped"
    assert health["heartbeat"].critical
