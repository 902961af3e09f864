"""Battery watchdog: thresholds, hysteresis, events and e-mail through a real SMTP server."""

import socket

import numpy as np
import pytest
from aiosmtpd.controller import Controller

from sage_robot.app.battery_watchdog import BatteryLevel, BatteryMonitor, BatteryWatchdogNode
from sage_robot.core.bus import Bus
from sage_robot.core.clock import SimClock
from sage_robot.core.config import load_profile
from sage_robot.core.msgs import BatteryState, Event
from sage_robot.core.node import NodeContext

from ..support.waits import sim_step_until, until


def test_hysteresis_does_not_flap():
    m = BatteryMonitor(warn=0.25, critical=0.10, hysteresis=0.03)
    rng = np.random.default_rng(1)
    changes = [m.update(0.25 + rng.uniform(-0.02, 0.02)) for _ in range(200)]  # jitter at the threshold
    assert [c for c in changes if c] == [BatteryLevel.WARN]
    assert m.update(0.09) is BatteryLevel.CRITICAL
    assert m.update(0.12) is None  # inside the band: still critical
    assert m.update(0.14) is BatteryLevel.WARN
    assert m.update(0.27) is None
    assert m.update(0.29) is BatteryLevel.OK


class Inbox:
    def __init__(self) -> None:
        self.messages: list[bytes] = []

    async def handle_DATA(self, server, session, envelope):
        self.messages.append(envelope.content)
        return "250 OK"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def smtp():
    inbox = Inbox()
    port = free_port()
    controller = Controller(inbox, hostname="127.0.0.1", port=port)
    controller.start()
    yield port, inbox
    controller.stop()


def make_node(port: int, interval_s: float = 900.0):
    settings = load_profile(
        None,
        {
            "email": {
                "smtp_host": "127.0.0.1",
                "smtp_port": port,
                "starttls": False,
                "recipients": ["ops@example.org"],
                "min_interval_s": interval_s,
            }
        },
    )
    clock = SimClock()
    bus = Bus(clock)
    node = BatteryWatchdogNode(NodeContext(bus, clock, settings))
    return node, bus, clock


async def feed(bus, clock, fractions):
    for f in fractions:
        bus.publish("/battery_state", BatteryState(clock.now(), 12.0 + 4.8 * f, f))
        await clock.step(0.02)


async def test_low_battery_event_and_one_mail(smtp):
    port, inbox = smtp
    node, bus, clock = make_node(port)
    events: list[Event] = []
    bus.subscribe("/sage/events", Event, events.append)
    await node.setup()
    await feed(bus, clock, [0.5, 0.3, 0.24, 0.26, 0.24, 0.23])  # jitter around 25 %
    await until(lambda: len(inbox.messages) == 1)
    await feed(bus, clock, [0.09, 0.08])
    await until(lambda: len(inbox.messages) == 2)
    kinds = [e.kind for e in events]
    assert kinds == ["battery_low", "battery_critical"]
    assert b"Battery critical" in inbox.messages[1]
    assert b"ops@example.org" in inbox.messages[1]
    await node._close()


async def test_dead_mail_server_never_stops_the_node():
    node, bus, clock = make_node(free_port())  # nothing listens there
    await node.setup()
    await feed(bus, clock, [0.2])
    # Retries back off on the simulated clock (2 + 4 + 8 s); each attempt runs in a thread.
    await sim_step_until(clock, lambda: node.mails_failed == 1, "the mail to be given up", 60.0,
                         step_s=1.0, real_pause_s=0.01)
    assert node.stats()["level"] == "warn"
    await node._close()
