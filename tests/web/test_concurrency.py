"""The issue's probes of goals and questions at once, on the real server (its own robot).

- A double click on a place button (two goals in the same instant), then Cancel: every
  request answers, the robot ends stopped, and a later goal still starts.
- Ten visitors ask at once: every request answers (an answer, or 429 from the per-address
  limit) and a later question is still answered.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from typing import Any

import httpx
import pytest

from sage_robot.core import topics
from sage_robot.core.msgs import Twist

from ..support.waits import wait_until

ANSWER_BOUND_S = 30.0  # each request answers within this (the clients' timeout: a hang fails)
PLACE = "GUELLY_DELLY"


@pytest.fixture(scope="module")
def operator(robot: Any) -> httpx.Client:
    client = httpx.Client(base_url=robot.url, timeout=ANSWER_BOUND_S, headers={"Origin": robot.url})
    assert client.post("/api/login", json={"password": robot.password}).status_code == 200
    return client


def _last_cmd(robot: Any) -> list[Twist]:
    got: list[Twist] = []
    robot.call(lambda: robot.bus.subscribe(topics.CMD_VEL, Twist, got.append, maxsize=10000))
    return got


def test_a_double_click_then_cancel_answers_and_leaves_the_robot_stopped(
    robot: Any, operator: httpx.Client
) -> None:
    cmds = _last_cmd(robot)
    with ThreadPoolExecutor(2) as pool:
        clicks = list(pool.map(lambda _: operator.post("/api/goal", json={"place": PLACE}), range(2)))
    assert [r.status_code for r in clicks] == [200, 200], [r.text for r in clicks]
    ids = [r.json()["goal_id"] for r in clicks]
    assert ids[0] != ids[1]
    assert operator.post("/api/cancel").status_code == 200
    assert robot.call(lambda: robot.bus.actions.active(topics.NAVIGATE_TO)) is None, "no goal left running"
    wait_until(lambda: cmds and cmds[-1].is_zero, "the robot to be told to stop")
    again = operator.post("/api/goal", json={"place": PLACE})  # navigation is not jammed
    assert again.status_code == 200
    handle = robot.call(lambda: robot.bus.actions.active(topics.NAVIGATE_TO))
    assert handle is not None
    assert handle.goal_id == again.json()["goal_id"]
    assert operator.post("/api/cancel").status_code == 200


def test_ten_simultaneous_questions_all_answer_and_the_brain_stays_up(robot: Any) -> None:
    def ask(text: str) -> httpx.Response:
        return httpx.post(f"{robot.url}/api/talk/text", json={"text": text}, timeout=ANSWER_BOUND_S)

    with ThreadPoolExecutor(10) as pool:  # each answers within ANSWER_BOUND_S, or raises
        codes = [r.status_code for r in pool.map(ask, (f"hello number {i}" for i in range(10)))]
    assert set(codes) <= {200, 429}, codes  # answered, or over the per-address limit
    assert codes.count(200) >= 5  # the limit's burst: these were answered, none was dropped

    def let_through() -> httpx.Response | None:
        resp = ask("are you still there?")
        return None if resp.status_code == 429 else resp

    # the limiter refills one question every 3 s
    later = wait_until(let_through, "the rate limiter to let a question through", ANSWER_BOUND_S, poll=0.5)
    assert later.status_code == 200, later.text
    assert later.json()["reply"], later.text
