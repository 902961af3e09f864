"""Walkers go around a robot that stands still instead of waiting for it forever."""

from __future__ import annotations

import math

import numpy as np

from sage_robot.sim.people import PERSON_RADIUS_M, ROBOT_GAP_M, TURN_BACK_S, Crowd, Lanes, PersonState

ROBOT_X_M = 5.0
ROBOT_RADIUS_M = 0.25
DT_S = 0.05


def _walk(width_m: float, robot_y_m: float, robot_speed: float = 0.0) -> tuple[PersonState, float]:
    """A walker patrols east at y = ``robot_y_m`` along a corridor ``width_m`` wide (y in
    0..width) straight at the robot; returns it after 20 s and its closest distance to the
    robot's centre."""
    p = PersonState(0, 2.0, robot_y_m, behaviour="walker", speed_mps=1.0, fixed=True,
                    patrol=[(9.0, robot_y_m)])
    crowd = Crowd([p], None, lambda x, y: min(y, width_m - y), np.random.default_rng(0))
    crowd.robot_speed = robot_speed
    robot = (ROBOT_X_M, robot_y_m, 0.0)
    closest = math.inf
    for k in range(int(20.0 / DT_S)):
        crowd.step(DT_S, k * DT_S, robot, ROBOT_RADIUS_M)
        closest = min(closest, math.hypot(p.x - robot[0], p.y - robot[1]))
    return p, closest


def test_a_walker_goes_around_a_halted_robot_on_the_side_with_room() -> None:
    # the robot stands off-centre in a 2 m corridor: the walker's side-step toward the near
    # wall leaves no room there, so it goes around the other side (it used to wait forever)
    p, closest = _walk(2.0, 1.3)
    assert p.x > 8.0  # got past
    assert closest >= PERSON_RADIUS_M + ROBOT_RADIUS_M + ROBOT_GAP_M - 1e-6


def test_a_walker_waits_when_the_robot_fills_the_corridor_or_drives() -> None:
    narrow, _ = _walk(1.0, 0.5)  # 1 m: no room to pass the robot
    assert narrow.x < ROBOT_X_M
    moving, _ = _walk(2.0, 1.3, robot_speed=0.5)  # a driving robot steers around people itself
    assert moving.x < ROBOT_X_M


def test_a_walker_on_the_lanes_turns_back_when_the_robot_fills_the_corridor() -> None:
    # a 1 m corridor along y = 0.5 from (0, 0.5) to (10, 0.5); the robot stands in it at x = 5
    lanes = Lanes([[0.0, 0.5], [10.0, 0.5]], [[0, 1, 0.4]])
    p = PersonState(0, 2.0, 0.5, behaviour="walker", speed_mps=1.0, node=1, prev_node=0, route=[(10.0, 0.5)])
    crowd = Crowd([p], lanes, lambda x, y: min(y, 1.0 - y), np.random.default_rng(0))
    robot = (ROBOT_X_M, 0.5, 0.0)
    stuck_at, westmost, closest = None, math.inf, math.inf
    for k in range(int((TURN_BACK_S + 7.0) / DT_S)):
        crowd.step(DT_S, k * DT_S, robot, ROBOT_RADIUS_M)
        if stuck_at is None and p.moving == 0.0:
            stuck_at = p.x
        westmost = min(westmost, p.x)
        closest = min(closest, math.hypot(p.x - robot[0], p.y - robot[1]))
    assert stuck_at is not None
    assert stuck_at < ROBOT_X_M  # it waited in front of the robot first
    assert westmost < stuck_at - 3.0  # then walked back the way it came
    assert closest >= PERSON_RADIUS_M + ROBOT_RADIUS_M + ROBOT_GAP_M - 1e-6
