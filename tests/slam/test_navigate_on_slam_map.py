"""Navigate on a map SLAM made: map half of the drawn corridor loop, save it (free_thresh 0.1),
then run the real map server, localization and navigator on the saved map while the
navigation tests' kinematic simulator moves the robot in the true world."""

from __future__ import annotations

import asyncio
import itertools
import math
from pathlib import Path

import yaml

from sage_robot.core import topics
from sage_robot.core.msgs.nav import NavigateGoal
from sage_robot.nav.slam.engine import Slam
from sage_robot.nav.slam.store import save_session

from ..nav.nav_sim import running, settings_for
from .synth import corridor_loop, loop_path, simulate

REAL_TIMEOUT_S = 120.0  # bound on the whole drive (wall clock, loaded machine)
START = (1.0, 0.0, 0.0)
GOAL = (12.0, 7.0, math.pi / 2)  # up the east corridor
ARRIVAL_TOLERANCE_M = 0.4  # goal tolerance 0.25 m on the estimate + localization error


async def test_navigator_reaches_a_place_on_the_slam_map(tmp_path: Path) -> None:
    world = corridor_loop()
    # Along the south side and up the east side, until 11 m north.
    truth = list(itertools.takewhile(lambda p: p[1] <= 11.0, loop_path(step_m=0.35)))
    drive = simulate(world, truth, yaw_drift=0.01)
    slam = Slam(initial_pose=truth[0])
    for k, (odom, scan) in enumerate(zip(drive.odom, drive.scans, strict=True)):
        slam.add_scan(0.1 * k, odom, scan)
    _, est = slam.trajectory_array()
    assert max(math.dist(e[:2], t[:2]) for e, t in zip(est, truth, strict=True)) < 0.1
    paths = save_session(slam, tmp_path, "map")
    places = {"START": START, "GOAL": GOAL}
    wp = {"places": [{"name": n, "pose": list(p), "aliases": [n.lower()]} for n, p in places.items()]}
    (tmp_path / "waypoints.yaml").write_text(yaml.safe_dump(wp), encoding="utf-8")
    settings = settings_for(Path(paths["yaml"]), "START")
    async with running(settings, world, START, speed=None) as (bus, _clock, sim):
        handle = await bus.actions.send_goal(topics.NAVIGATE_TO, NavigateGoal(place="GOAL"))
        result = await asyncio.wait_for(handle.result(), REAL_TIMEOUT_S)
        assert result.ok, result.message
        assert result.value.succeeded
        x, y, _ = sim.pose
        assert math.hypot(x - GOAL[0], y - GOAL[1]) <= ARRIVAL_TOLERANCE_M
        assert sim.collisions == 0
