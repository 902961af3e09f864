"""Scenarios: parsing with clear errors, the world node on the simulated clock, `sage sim --headless`."""

from __future__ import annotations

import asyncio
import json
import math
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from sage_robot.app.launcher import NodeSpec
from sage_robot.app.runtime import make_context, run_launcher
from sage_robot.core import topics
from sage_robot.core.config import load_profile
from sage_robot.core.errors import ConfigError
from sage_robot.core.geometry import wrap_angle
from sage_robot.core.msgs import CompressedImage, Event, LaserScan, Odometry
from sage_robot.core.msgs.sim import People, SpeakerBearing
from sage_robot.core.msgs.voice import Doa
from sage_robot.sim.node import SCENARIO_RESOURCE, WORLD_RESOURCE, WorldNode
from sage_robot.sim.scenario import load_scenario, parse_scenario

BENCH_RUN = """
name: bench_in_the_way
seed: 4
pedestrians: 0
default_clutter: false
people:
  - {kind: stander, at: [50.3, 59.8]}
clutter:
  - {name: test_bench, kind: bench, center: [50.0, 57.5], size: [0.45, 1.6], height: 0.45}
events:
  - {at: 0.5, cmd_vel: [0.5, 0.0]}
"""


def write(tmp_path: Path, text: str, name: str = "s.yaml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("speed: 3\n", "unknown key(s) speed"),
        ("events:\n  - {at: 1, cmd_vel: fast}\n", "cmd_vel must be [v m/s, w rad/s]"),
        ("events:\n  - {at: 1, dance: true}\n", "needs exactly one of"),
        ("battery: 1.5\n", "battery is a charge fraction"),
        ("clutter:\n  - {size: [1, 1]}\n", "needs 'center: [x, y]'"),
        ("[1, 2]\n", "a scenario is a YAML mapping"),
    ],
)
def test_bad_scenarios_say_what_is_wrong(tmp_path: Path, text: str, message: str) -> None:
    with pytest.raises(
        ConfigError, match=message.replace("[", r"\[").replace("(", r"\(").replace(")", r"\)")
    ):
        load_scenario(write(tmp_path, text))


def test_scenario_fields_and_overrides(tmp_path: Path) -> None:
    sc = load_scenario(write(tmp_path, BENCH_RUN + "map: other/map.yaml\nduration_s: 5\nbattery: 0.4\n"))
    assert sc.name == "bench_in_the_way"
    assert sc.duration_s == 5.0
    assert sc.battery == 0.4
    assert sc.clutter[0].name == "test_bench"
    assert sc.events[0].value == (0.5, 0.0)
    over = sc.settings_overrides()
    assert over["sim"] == {"world_map": str(tmp_path / "other/map.yaml"), "seed": 4, "pedestrians": 0}
    assert over["nav"]["map"] == str(tmp_path / "other/map.yaml")
    with pytest.raises(ConfigError, match="not found"):
        load_scenario(tmp_path / "missing.yaml")


async def test_world_node_runs_a_scenario_on_the_sim_clock() -> None:
    scenario = parse_scenario(__import__("yaml").safe_load(BENCH_RUN), "bench_run")
    settings = load_profile(None, {"sim": {"speed": None, **scenario.settings_overrides()["sim"]}})
    ctx = make_context(settings, simulated=True)
    ctx.resources[SCENARIO_RESOURCE] = scenario
    got: dict[str, list[Any]] = {}

    def collect(topic: str, kind: type) -> None:
        got[topic] = []
        ctx.bus.subscribe(topic, kind, got[topic].append, maxsize=1000)

    streams: list[tuple[str, type]] = [
        (topics.SCAN, LaserScan), (topics.SIM_COLLISIONS, Event), (topics.SIM_TRUTH, Odometry),
        (topics.SIM_PEOPLE, People), (topics.SIM_SPEAKER, SpeakerBearing), (topics.CAMERA, CompressedImage),
        (topics.SIM_SPEAKER_BEARING, Doa),
    ]  # fmt: skip
    for topic, kind in streams:
        collect(topic, kind)
    await run_launcher(ctx, [NodeSpec("sim_world", WorldNode, True)], until=6.0)
    world = ctx.resources[WORLD_RESOURCE]
    assert 58 <= len(got[topics.SCAN]) <= 61  # 10 Hz
    assert 290 <= len(got[topics.SIM_TRUTH]) <= 301  # 50 Hz
    assert got[topics.CAMERA]
    assert got[topics.SIM_PEOPLE]
    # The robot drove east from the dock into the bench; the lidar never saw the bench.
    assert world.collisions == 1
    (event,) = got[topics.SIM_COLLISIONS]
    assert event.kind == "collision"
    assert event.data["name"] == "low_obstacle:test_bench"
    assert world.x == pytest.approx(50.0 - 0.225 - 0.25, abs=0.02)
    last = got[topics.SCAN][-1]
    ahead = last.ranges[np.argmin(np.abs(last.angles))]
    assert ahead > 1.0  # the corridor's far wall (1.6 m), not the bench 0.1 m away
    # The stander 2.4 m north-east is "the speaker" once the robot is within 3 m.
    assert got[topics.SIM_SPEAKER][-1].present
    assert got[topics.SIM_SPEAKER_BEARING]
    assert got[topics.SIM_SPEAKER_BEARING][-1].source == "sim"
    assert 90.0 < got[topics.SIM_SPEAKER_BEARING][-1].angle_deg < 180.0  # ahead and to the left


def run_cli(*args: str, timeout: float = 150.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "sage_robot.cli.main", *args], capture_output=True,
                          text=True, timeout=timeout)  # fmt: skip


def test_sage_sim_headless_runs_a_scenario_and_prints_a_summary(tmp_path: Path) -> None:
    """The whole chain: scenario /cmd_vel -> serial bridge -> pty -> firmware model -> world body,
    into the bench the lidar cannot see."""
    path = write(tmp_path, BENCH_RUN + "duration_s: 8\n")
    proc = run_cli("--log-level", "WARNING", "sim", "--headless", "--fast", "--json", "--scenario", str(path),
                   "--nodes", "sim_world,mcu_sim,serial_bridge")  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    summary = json.loads(proc.stdout.strip().splitlines()[-1])
    assert summary["scenario"] == "bench_in_the_way"
    assert summary["sim_time_s"] == pytest.approx(8.0, abs=0.02)
    assert summary["collisions_by_kind"] == {"low_obstacle": 1}
    assert summary["pose"][0] == pytest.approx(50.0 - 0.225 - 0.25, abs=0.03)  # stopped at the bench
    assert summary["distance_m"] > 2.0
    assert summary["nodes_failed"] == []
    assert summary["real_time_factor"] > 0


@pytest.mark.parametrize("watched", [False, True])
async def test_the_camera_renders_only_for_a_subscriber(watched: bool) -> None:
    settings = load_profile(None, {"sim": {"speed": None, "camera_hz": 15, "pedestrians": 0}})
    ctx = make_context(settings, simulated=True)
    frames: list[CompressedImage] = []
    if watched:
        ctx.bus.subscribe(topics.CAMERA, CompressedImage, frames.append, maxsize=100)
    launcher = await run_launcher(ctx, [NodeSpec("sim_world", WorldNode, True)], until=2.0)
    rendered = launcher.nodes["sim_world"].frames  # type: ignore[attr-defined]
    assert (rendered > 0) is watched
    assert len(frames) == rendered


def test_headless_sets_no_camera_frames() -> None:
    import argparse

    from sage_robot.cli.run import _overrides

    args = argparse.Namespace(speed=None, fast=True, seed=None, headless=True)
    assert _overrides(args, None)["sim"]["camera_hz"] == 0
    args.headless = False
    assert "camera_hz" not in _overrides(args, None).get("sim", {})


def test_headless_runs_open_no_listeners_and_print_a_tidy_summary(capsys: Any) -> None:
    from sage_robot.app.runtime import specs_for
    from sage_robot.cli.run import _print_summary, sim_specs

    full = {s.name for s in specs_for("sim")}
    assert {"web", "foxglove"} <= full  # present when someone watches...
    headless = {s.name for s in sim_specs(True)}
    assert headless == full - {"web", "foxglove"}  # ...never in a one-shot run
    with pytest.raises(ConfigError, match="foxglove not in the sim profile"):
        sim_specs(True, "sim_world,foxglove")
    base = {"sim_time_s": 1.0, "wall_time_s": 1.0, "real_time_factor": 1.0, "distance_m": 1.0,
            "pose": [1.0, 2.0, 0.0], "goals": [], "nodes_restarted": []}  # fmt: skip
    _print_summary({**base, "collisions": 0, "collisions_by_kind": {}}, as_json=False)
    _print_summary({**base, "collisions": 1, "collisions_by_kind": {"wall": 1}}, as_json=False)
    out = capsys.readouterr().out
    assert "collisions: 0, final pose [1.0, 2.0, 0.0]" in out
    assert "collisions: 1 {'wall': 1}, final pose" in out


def test_sage_sim_reports_a_bad_scenario_in_one_line(tmp_path: Path) -> None:
    proc = run_cli("sim", "--headless", "--scenario", str(write(tmp_path, "events: 3\n")), timeout=60)
    assert proc.returncode == 2
    assert proc.stderr.strip().startswith("sage: error:")
    assert "Traceback" not in proc.stderr


def test_bundled_scenarios_load_and_build() -> None:
    from sage_robot.sim.scenario import bundled_scenarios
    from sage_robot.sim.setup import build_world

    names = bundled_scenarios()
    assert {"low_bench", "crowded_corridor", "visitor", "teleop_drive"} <= set(names)
    for name in names:
        sc = load_scenario(name)
        over = sc.settings_overrides()
        world = build_world(load_profile(None, over or None), sc)  # poses valid, people placed
        assert len(world.crowd.people) == (sc.pedestrians or 0) + len(sc.people), name


async def test_teleop_scenario_drives_down_the_corridor() -> None:
    scenario = load_scenario("teleop_drive")
    settings = load_profile(
        None, {"sim": {"speed": None, "camera_hz": 0, **scenario.settings_overrides()["sim"]}}
    )
    ctx = make_context(settings, simulated=True)
    ctx.resources[SCENARIO_RESOURCE] = scenario
    await run_launcher(ctx, [NodeSpec("sim_world", WorldNode, True)], until=20.0)
    world = ctx.resources[WORLD_RESOURCE]
    assert world.collisions == 0
    assert world.x == pytest.approx(50.0, abs=0.3)  # in the corridor's middle
    assert world.y < 57.5 - 6.0  # drove south


async def _teleop_end(node_names: tuple[str, ...]) -> Any:
    from sage_robot.app.runtime import specs_for

    scenario = load_scenario("teleop_drive")
    settings = load_profile(
        None, {"sim": {"speed": None, "camera_hz": 0, **scenario.settings_overrides()["sim"]}}
    )
    ctx = make_context(settings, simulated=True)
    ctx.resources[SCENARIO_RESOURCE] = scenario
    specs = [s for s in specs_for("sim") if s.name in node_names]
    await run_launcher(ctx, specs, until=scenario.duration_s)
    return ctx.resources[WORLD_RESOURCE]


async def test_teleop_through_the_serial_bridge_and_firmware_follows_direct_drive() -> None:
    """/cmd_vel -> bridge -> pty -> firmware model (PI, ESC, motors) -> world ends where
    the ideal direct drive does: a loose drive chain (over-rotated turn) hits the wall."""
    direct = await _teleop_end(("sim_world",))
    chain = await _teleop_end(("sim_world", "mcu_sim", "serial_bridge"))
    assert direct.collisions == 0
    assert chain.collisions == 0
    assert math.hypot(chain.x - direct.x, chain.y - direct.y) < 0.3, (chain.pose, direct.pose)
    assert abs(wrap_angle(chain.pose[2] - direct.pose[2])) < math.radians(1.0)


def test_web_addresses_and_node_selection_errors() -> None:
    from sage_robot.cli.run import web_addresses

    urls = web_addresses(load_profile(None, {"web": {"port": 8123}}))  # on every address: HTTPS
    assert urls[0] == "https://localhost:8123/"
    assert all(u.startswith("https://localhost:8123/") for u in urls)
    local = web_addresses(load_profile(None, {"web": {"port": 8123, "host": "127.0.0.1"}}))
    assert local[0] == "http://localhost:8123/"
    proc = run_cli("sim", "--headless", "--nodes", "sim_world,warp_drive", "--duration", "1", timeout=60)
    assert proc.returncode == 2
    assert "warp_drive not in the sim profile" in proc.stderr


def test_a_real_map_without_lanes_gets_people_on_its_floor(shared_data: Any) -> None:
    from sage_robot.sim.setup import build_world

    path = shared_data("maps/willow-full/willow-full.yaml")
    sc = parse_scenario({"map": str(path), "start": [10.0, 10.0, 0.0], "pedestrians": 5}, "willow")
    world = build_world(load_profile(None, sc.settings_overrides()), sc)
    assert world.crowd.lanes is None
    assert len(world.crowd.people) == 5
    for _ in range(500):
        world.step(0.01)
    for p in world.crowd.people:
        assert world.raycaster.is_free(p.x, p.y), (p.x, p.y)
    bad = parse_scenario({"map": str(path), "start": [-5.0, 10.0, 0.0]}, "willow")
    with pytest.raises(ConfigError, match="not on free floor"):
        build_world(load_profile(None, bad.settings_overrides()), bad)


async def test_scenario_battery_reaches_the_firmware_model() -> None:
    from sage_robot.app.runtime import specs_for

    scenario = parse_scenario({"battery": 0.3, "pedestrians": 0}, "low battery")
    settings = load_profile(None, {"sim": {"speed": None, "camera_hz": 0, "pedestrians": 0}})
    ctx = make_context(settings, simulated=True)
    ctx.resources[SCENARIO_RESOURCE] = scenario
    specs = [s for s in specs_for("sim") if s.name in ("sim_world", "mcu_sim")]
    launcher = await run_launcher(ctx, specs, until=2.0)
    charge = launcher.nodes["mcu_sim"].firmware.battery.charge  # type: ignore[attr-defined]
    assert charge == pytest.approx(0.3, abs=0.001)


async def test_a_failing_physics_step_restarts_the_node_and_keeps_the_world() -> None:
    settings = load_profile(None, {"sim": {"speed": None, "camera_hz": 0, "pedestrians": 0}})
    ctx = make_context(settings, simulated=True)
    calls = {"n": 0}

    async def break_once(launcher: Any) -> None:
        for _ in range(100):  # the node's setup runs on the next loop turns
            if WORLD_RESOURCE in ctx.resources:
                break
            await asyncio.sleep(0)
        world = ctx.resources[WORLD_RESOURCE]
        real_step = world.step

        def step(dt: float) -> None:
            calls["n"] += 1
            if calls["n"] == 50:
                raise ValueError("boom")
            real_step(dt)

        world.step = step  # type: ignore[method-assign]  # on purpose: the step fails once

    launcher = await run_launcher(
        ctx, [NodeSpec("sim_world", WorldNode, True)], until=3.0, after_start=break_once
    )
    health = launcher.health["sim_world"]
    assert health.restarts == 1
    assert "boom" in health.last_error
    assert calls["n"] > 100  # the same world kept stepping after the restart


async def test_goal_and_heard_events_without_navigation() -> None:
    from sage_robot.core.msgs import Text
    from sage_robot.sim.node import SUMMARY_RESOURCE

    events = [{"at": 0.5, "goal": "the cafe"}, {"at": 0.7, "heard": "hello"}]
    scenario = parse_scenario({"pedestrians": 0, "events": events}, "goals")
    ctx = make_context(load_profile(None, {"sim": {"speed": None, "camera_hz": 0}}), simulated=True)
    ctx.resources[SCENARIO_RESOURCE] = scenario
    heard: list[Text] = []
    ctx.bus.subscribe(topics.HEARD, Text, heard.append)
    await run_launcher(ctx, [NodeSpec("sim_world", WorldNode, True)], until=1.0)
    (goal,) = ctx.resources[SUMMARY_RESOURCE]["goals"]
    assert goal["goal"] == "the cafe"
    assert goal["status"] == "no navigation node"
    assert [t.data for t in heard] == ["hello"]  # the notification, as the voice pipeline's
    (talk,) = ctx.resources[SUMMARY_RESOURCE]["conversations"]
    assert talk["heard"] == "hello"
    assert talk["status"] == "no brain"
