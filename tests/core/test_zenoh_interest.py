"""Which topics come in from other processes: only those read here (a subscription, a latched
declaration, ``latest()``, a tap's ``want``), or all while ``want_all`` holds; and a latched
topic's last value reaches a process that starts after it was published (issue #24)."""

from __future__ import annotations

import asyncio
from collections import Counter
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

pytest.importorskip("zenoh")

from sage_robot.core import topics
from sage_robot.core.bus import Bus
from sage_robot.core.clock import WallClock
from sage_robot.core.config.bus import BusSettings, ZenohSettings
from sage_robot.core.msgs import HealthReport, LaserScan, OccupancyGrid
from sage_robot.core.transport.zenoh_bus import ZenohTransport
from tests.core.zenoh_peer import SCAN_HZ, big_map, free_port, running_peer, unique_robot
from tests.support.waits import until

QUIET_S = 10 / SCAN_HZ  # ten of the peer's scans: long enough to see one that should not come


@pytest.fixture
def joined() -> Iterator[tuple[Bus, ZenohTransport]]:
    """A bus in this process joined to a peer process that publishes /scan and, once at its
    start, the latched /sage/health."""
    robot, port = unique_robot(), free_port()
    with running_peer(robot, port):
        settings = BusSettings(
            transport="zenoh",
            robot_id=robot,
            zenoh=ZenohSettings(listen=(f"tcp/127.0.0.1:{free_port()}",), connect=(f"tcp/127.0.0.1:{port}",)),
        )
        transport = ZenohTransport(settings)
        try:
            yield Bus(WallClock(), transport), transport
        finally:
            transport.close()


async def test_a_process_that_starts_late_gets_a_latched_value_at_once(
    joined: tuple[Bus, ZenohTransport],
) -> None:
    bus, _ = joined
    bus.declare(topics.HEALTH)  # latched: the peer published it once, before this bus existed
    await until(lambda: bus.latest(topics.HEALTH) is not None, "the peer's last health report came")
    report = bus.latest(topics.HEALTH)
    assert isinstance(report, HealthReport)
    assert [n.name for n in report.nodes] == ["peer"]
    late = bus.subscribe(topics.HEALTH, HealthReport)  # a late subscriber here gets it too
    assert late.get_nowait() == report


async def test_a_building_sized_latched_map_reaches_a_process_that_starts_late(
    joined: tuple[Bus, ZenohTransport],
) -> None:
    """3.2 MB, fifty Zenoh batches, as the last value of a latched topic: the web process gets
    the navigator's /map so (Zenoh's low-latency transport lost it: docs/benchmarks.md)."""
    bus, _ = joined
    bus.declare(topics.MAP)
    await until(lambda: bus.latest(topics.MAP) is not None, "the peer's /map came", timeout=30)
    grid = bus.latest(topics.MAP)
    assert isinstance(grid, OccupancyGrid)
    assert np.array_equal(grid.data, big_map().data)


async def test_topics_nobody_here_reads_stay_away_and_want_all_brings_them(
    joined: tuple[Bus, ZenohTransport],
) -> None:
    bus, transport = joined
    seen: Counter[str] = Counter()

    def tap(topic: str, msg: Any) -> None:
        seen[topic] += 1

    bus.add_tap(tap)
    bus.declare(topics.HEALTH)
    await until(lambda: bus.latest(topics.HEALTH) is not None, "the peer is connected")
    await asyncio.sleep(QUIET_S)
    assert seen[topics.SCAN] == 0  # published by the peer all along, read by nobody here
    release = bus.want_all()
    await until(lambda: seen[topics.SCAN] >= 3, "scans came while want_all held")
    release()
    release()  # a second call changes nothing
    await asyncio.sleep(QUIET_S / 2)  # in flight when released
    after = seen[topics.SCAN]
    await asyncio.sleep(QUIET_S)
    assert seen[topics.SCAN] == after
    scans = bus.subscribe(topics.SCAN, LaserScan)  # a reader: they come again
    assert isinstance(await asyncio.wait_for(scans.get(), 10), LaserScan)
    assert transport.rejected == 0
