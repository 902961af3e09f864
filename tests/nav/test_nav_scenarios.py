"""Harder scenarios: the default building, a kidnapped robot, keepout and speed zones."""

from __future__ import annotations

import asyncio
import math

from sage_robot.core import topics
from sage_robot.core.config import Settings
from sage_robot.core.mapio import read_map
from sage_robot.core.msgs import Event, Pose2D, PoseWithCovariance, Text
from sage_robot.core.msgs.nav import LocalizationHealth, NavigateGoal
from sage_robot.core.paths import map_yaml
from sage_robot.nav.mapdata import load_for

from ..support.grids import blank_like, draw, fill
from ..support.waits import sim_until
from .nav_sim import running, settings_for, write_building
from .test_localization_control import FLOOR
from .test_navigator import GOAL_TOLERANCE_TRUTH_M, REAL_TIMEOUT_S, WIDE

A, B = (1.5, 2.0, 0.0), (9.5, 2.0, 0.0)
COVARIANCE = (0.04, 0.0, 0.0, 0.0, 0.04, 0.0, 0.0, 0.0, 0.01)  # 0.2 m, 0.1 rad


def _events(bus):
    got: list[Event] = []
    bus.subscribe(topics.EVENTS, Event, got.append, maxsize=100)
    return got


async def test_drives_between_places_in_the_default_building() -> None:
    settings = Settings()
    grid = read_map(map_yaml(settings))
    places = load_for(settings).places
    start = places.get("DOCKING_STATION").pose.as_tuple()
    goal = places.get("BATHROOMS").pose
    async with running(settings, grid, start, odom_scale=1.015) as (bus, _clock, sim):
        handle = await bus.actions.send_goal(topics.NAVIGATE_TO, NavigateGoal(place="the bathrooms"))
        result = await asyncio.wait_for(handle.result(), 2 * REAL_TIMEOUT_S)
        assert result.ok, result.message
        assert math.hypot(sim.pose[0] - goal.x, sim.pose[1] - goal.y) <= GOAL_TOLERANCE_TRUTH_M
        assert sim.collisions == 0
        assert not sim.reversed_commands()
        assert result.value.distance_travelled_m > 15.0


async def test_kidnapped_robot_notices_and_relocalizes(tmp_path) -> None:
    grid = draw(FLOOR, 0.05, scale=10)
    start, goal = (3.0, 5.5, 0.0), (12.0, 2.0, math.pi / 2)
    path = write_building(tmp_path, grid, {"START": start, "GOAL": goal})
    settings = settings_for(path, "START")
    async with running(settings, grid, start) as (bus, clock, sim):
        events = _events(bus)
        health: list[LocalizationHealth] = []
        bus.subscribe(topics.LOC_HEALTH, LocalizationHealth, health.append, maxsize=1000)
        await sim_until(clock, lambda: len(health) > 10, "health reports", 10)
        assert health[-1].score > 0.8
        assert not health[-1].lost
        sim.teleport(8.0, 5.5, -math.pi / 2)  # carried off while standing
        await asyncio.wait_for(sim_until(clock, lambda: health[-1].lost, "lost", 10), REAL_TIMEOUT_S)
        handle = await bus.actions.send_goal(topics.NAVIGATE_TO, NavigateGoal(place="GOAL"))
        result = await asyncio.wait_for(handle.result(), REAL_TIMEOUT_S)
        kinds = [e.kind for e in events]
        assert "lost" in kinds
        assert "relocalized" in kinds
        assert result.ok, result.message
        assert math.hypot(sim.pose[0] - goal[0], sim.pose[1] - goal[1]) <= GOAL_TOLERANCE_TRUTH_M
        assert health[-1].score > 0.8
        assert sim.collisions == 0
        assert not sim.reversed_commands()


async def test_keepout_zone_is_never_entered(tmp_path) -> None:
    grid = draw(WIDE, 0.05, scale=10)
    keepout = fill(blank_like(grid), 4.0, 1.6, 7.0, 3.5, 100)  # leaves a lane along the bottom (y < 1.6)
    path = write_building(tmp_path, grid, {"ROOM_A": A, "ROOM_B": B}, keepout=keepout)
    async with running(settings_for(path, "ROOM_A"), grid, A) as (bus, _clock, sim):
        handle = await bus.actions.send_goal(topics.NAVIGATE_TO, NavigateGoal(place="ROOM_B"))
        result = await asyncio.wait_for(handle.result(), REAL_TIMEOUT_S)
        assert result.ok, result.message
        inside = [(x, y) for _, x, y, _ in sim.truth if 4.0 < x < 7.0 and 1.6 < y < 3.5]
        assert not inside
        assert max(y for _, x, y, _ in sim.truth if 4.0 < x < 7.0) < 1.6  # it took the lane
        assert sim.collisions == 0
        assert not sim.reversed_commands()


async def test_speed_zone_is_obeyed(tmp_path) -> None:
    grid = draw(WIDE, 0.05, scale=10)
    speed = fill(blank_like(grid), 4.0, 0.0, 7.0, 4.0, 30)  # 30 % of top speed across the hall
    path = write_building(tmp_path, grid, {"ROOM_A": A, "ROOM_B": B}, speed=speed)
    async with running(settings_for(path, "ROOM_A"), grid, A) as (bus, _clock, sim):
        handle = await bus.actions.send_goal(topics.NAVIGATE_TO, NavigateGoal(place="ROOM_B"))
        result = await asyncio.wait_for(handle.result(), REAL_TIMEOUT_S)
        assert result.ok, result.message
        limit = 0.3 * settings_for(path, "ROOM_A").robot.max_linear_mps
        in_zone = [c.linear_x for _, c, (x, _y, _t) in sim.cmds if 4.3 < x < 6.7]
        outside = [c.linear_x for _, c, (x, _y, _t) in sim.cmds if x < 3.5 or x > 7.5]
        assert in_zone
        assert max(in_zone) <= limit + 1e-6
        assert max(outside) > 2 * limit  # it does speed up again
        assert not sim.reversed_commands()


async def test_ekf_with_gyro_drives_despite_slipping_wheels(tmp_path) -> None:
    grid = draw(WIDE, 0.05, scale=10)
    path = write_building(tmp_path, grid, {"ROOM_A": A, "ROOM_B": B})
    settings = settings_for(path, "ROOM_A", use_ekf=True)
    async with running(settings, grid, A, odom_w_scale=1.15, imu=True) as (bus, _clock, sim):
        handle = await bus.actions.send_goal(topics.NAVIGATE_TO, NavigateGoal(place="ROOM_B"))
        result = await asyncio.wait_for(handle.result(), REAL_TIMEOUT_S)
        assert result.ok, result.message
        assert math.hypot(sim.pose[0] - B[0], sim.pose[1] - B[1]) <= GOAL_TOLERANCE_TRUTH_M
        assert sim.collisions == 0
        assert not sim.reversed_commands()


async def test_initial_pose_can_be_set_at_run_time(tmp_path) -> None:
    grid = draw(FLOOR, 0.05, scale=10)
    here, elsewhere = (3.0, 5.5, 0.0), (12.0, 2.0, math.pi / 2)
    path = write_building(tmp_path, grid, {"HERE": here, "ELSEWHERE": elsewhere})
    async with running(settings_for(path, "ELSEWHERE"), grid, here) as (bus, clock, _sim):
        health: list[LocalizationHealth] = []
        bus.subscribe(topics.LOC_HEALTH, LocalizationHealth, health.append, maxsize=1000)
        await sim_until(clock, lambda: len(health) > 10, "health reports", 10)
        assert health[-1].lost  # it starts at the wrong place and knows it
        bus.publish(topics.INITIAL_POSE, PoseWithCovariance(clock.now(), "map", Pose2D(*here), COVARIANCE))
        await sim_until(clock, lambda: not health[-1].lost and health[-1].score > 0.8, "a good fit", 10)
        where = await bus.call(topics.WHERE_AM_I, Text(""))
        assert where.nearest_place == "HERE"
        assert where.localized
        assert where.distance_m < 0.3


async def test_steps_away_from_a_corner_it_stopped_too_close_to(tmp_path) -> None:
    """The all-pairs benchmark left the robot stopped at this junction, 0.17 m (padded) from a
    door jamb: every forward arc toward the path got closer, and it never reverses. It turns
    toward open floor, creeps clear, and goes on."""
    settings = Settings()
    grid = read_map(map_yaml(settings))
    goal = load_for(settings).places.get("HEAT_POWER_LAB").pose.as_tuple()
    start = (50.85, 41.3, -0.75)
    path = write_building(tmp_path, grid, {"START": start, "HEAT_POWER_LAB": goal})
    async with running(settings_for(path, "START"), grid, start) as (bus, _clock, sim):
        handle = await bus.actions.send_goal(topics.NAVIGATE_TO, NavigateGoal(place="heat power lab"))
        result = await asyncio.wait_for(handle.result(), 2 * REAL_TIMEOUT_S)
        assert result.ok, result.message
        assert math.hypot(sim.pose[0] - goal[0], sim.pose[1] - goal[1]) <= GOAL_TOLERANCE_TRUTH_M
        assert sim.collisions == 0
        assert not sim.reversed_commands()
