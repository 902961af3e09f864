"""The navigator's social events (issue #20) reach the kiosk face's status socket as the
``social`` channel; other events stay on the operator's event log only."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any, cast

import pytest

from sage_robot.core import topics
from sage_robot.core.config import Settings
from sage_robot.core.msgs import Event
from sage_robot.core.msgs.nav import NavigateFeedback, NavState
from sage_robot.web.hub import Hub
from sage_robot.web.sockets import STATUS_CHANNELS

WAIT_MS = 30_000


def _hub() -> Hub:
    node = SimpleNamespace(bus=None, clock=None, settings=Settings.model_validate({}))
    return Hub(cast(Any, node))  # the hub reads only bus, clock and settings here


def test_social_events_reach_the_status_channel() -> None:
    hub = _hub()
    listener = hub.listen(STATUS_CHANNELS)
    hub._on_event(Event(3.0, "navigator", "arrived", "arrived at the lab", {}))
    assert "social" not in hub.latest
    hub._on_event(Event(4.0, "navigator", "pulling_over", "let me make room for you to pass", {}))
    assert hub.latest["social"]["type"] == "social"
    assert hub.latest["social"]["kind"] == "pulling_over"
    assert hub.latest["social"]["message"] == "let me make room for you to pass"
    assert "social" in listener.dirty
    assert [e["kind"] for e in hub.events] == ["arrived", "pulling_over"]  # the teleop log has both


@pytest.mark.browser
def test_the_face_says_a_social_event_on_the_guide_line(browser: Any, robot: Any) -> None:
    face = browser.new_page(viewport={"width": 1280, "height": 800})
    try:
        face.goto(f"{robot.url}/face")
        face.wait_for_selector("#link.up", timeout=WAIT_MS)
        robot.publish(topics.NAV_STATE, NavigateFeedback(NavState.DRIVING, "HESSE_CENTER", 12.4, 20.0))
        face.wait_for_function(
            "document.getElementById('guide-title').textContent === 'Hesse Center'", timeout=WAIT_MS
        )
        robot.publish(topics.EVENTS, Event(1.0, "navigator", "pulling_over", "let me make room", {}))
        face.wait_for_function(
            "document.getElementById('guide-progress').textContent === 'Making room for people to pass…'",
            timeout=WAIT_MS,
        )
    finally:
        face.close()
