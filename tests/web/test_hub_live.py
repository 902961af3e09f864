"""Odometry is a page-only stream in the web's hub (#24): subscribed while a page is open, and
never stale when the next page opens or when "place at the robot" asks without a page."""

from __future__ import annotations

import asyncio
import math
from types import SimpleNamespace
from typing import Any, cast

from sage_robot.core import topics
from sage_robot.core.bus import Bus
from sage_robot.core.clock import SimClock
from sage_robot.core.config import Settings
from sage_robot.core.msgs import Odometry, Pose2D, PoseStamped, Twist
from sage_robot.web.hub import Hub
from sage_robot.web.sockets import LIVE_CHANNELS as PAGE_CHANNELS

ODOM_PERIOD_S = 0.02  # the bridge's 50 Hz
WAIT_S = 5.0


def _hub(bus: Bus, clock: SimClock) -> Hub:
    settings = Settings.model_validate({})
    node = SimpleNamespace(bus=bus, clock=clock, settings=settings, subscribe=bus.subscribe)
    hub = Hub(cast(Any, node))
    hub.start()
    return hub


async def _settle() -> None:
    for _ in range(5):  # the subscriptions' pumps run on the loop
        await asyncio.sleep(0)


async def test_odometry_flows_only_while_a_page_is_open_and_never_goes_stale() -> None:
    clock = SimClock()
    bus = Bus(clock)
    hub = _hub(bus, clock)
    bus.publish(topics.MAP_ODOM, PoseStamped(0.0, "map", Pose2D(10.0, 0.0, 0.0)))  # odom sits 10 m east
    await _settle()
    assert not bus.has_readers(topics.ODOM), "no page: nobody in the web reads odometry"
    page = hub.listen(PAGE_CHANNELS)
    await _settle()
    assert bus.has_readers(topics.ODOM)
    bus.publish(topics.ODOM, Odometry(0.0, Pose2D(1.0, 2.0, 0.0), Twist()))
    await _settle()
    assert hub.latest["pose"]["frame"] == "map"
    assert math.isclose(hub.latest["pose"]["x"], 11.0)
    assert math.isclose(hub.latest["pose"]["y"], 2.0)
    hub.unlisten(page)
    await _settle()
    assert not bus.has_readers(topics.ODOM)
    assert "pose" not in hub.latest, "the next page must not see this pose"
    assert "odom" not in hub.latest
    assert hub.robot_pose is None


async def test_place_at_the_robot_without_a_page_waits_for_one_fresh_odometry() -> None:
    clock = SimClock()
    bus = Bus(clock)
    hub = _hub(bus, clock)
    bus.publish(topics.MAP_ODOM, PoseStamped(0.0, "map", Pose2D(10.0, 0.0, math.pi / 2)))
    page = hub.listen(PAGE_CHANNELS)
    await _settle()
    bus.publish(topics.ODOM, Odometry(0.0, Pose2D(1.0, 0.0, 0.0), Twist()))
    await _settle()
    hub.unlisten(page)  # the robot drives on with no page open
    bus.publish(topics.ODOM, Odometry(1.0, Pose2D(3.0, 0.0, 0.0), Twist()))  # nobody reads it

    async def bridge() -> None:
        while True:
            await asyncio.sleep(ODOM_PERIOD_S)
            bus.publish(topics.ODOM, Odometry(2.0, Pose2D(4.0, 0.0, 0.0), Twist()))

    driving = asyncio.get_running_loop().create_task(bridge())
    try:
        pose, frame = await asyncio.wait_for(hub.current_pose(timeout_s=1.0), WAIT_S)
    finally:
        driving.cancel()
    assert frame == "map"
    assert pose is not None
    assert math.isclose(pose[0], 10.0, abs_tol=1e-9)
    assert math.isclose(pose[1], 4.0)
    assert not bus.has_readers(topics.ODOM), "the one-off reader is gone"
    assert "pose" not in hub.latest, "a one-off look does not feed the pages' channel"


async def test_without_odometry_the_pose_is_localizations() -> None:
    clock = SimClock()
    bus = Bus(clock)
    hub = _hub(bus, clock)
    assert await hub.current_pose(timeout_s=0.05) == (None, "")
    from sage_robot.core.msgs import PoseWithCovariance

    bus.publish(topics.AMCL_POSE, PoseWithCovariance(0.0, "map", Pose2D(5.0, 6.0, 0.0)))
    await _settle()
    pose, frame = await hub.current_pose(timeout_s=0.05)
    assert (pose, frame) == ((5.0, 6.0, 0.0), "map")
