"""The kiosk face as the robot's screen (issue #21), in a real Chromium against the simulator.

Idle, it invites ("Say 'Hey Jarvis' or scan me"); a typed /talk question is captioned on the
face with the robot's answer; the guiding card shows where the robot is taking the visitor
(the place's title, not its code name) and its Stop cancels the walk; announcements are
captioned too; /api/places carries each place's title.
"""

from __future__ import annotations

from typing import Any

import httpx
import pytest

from sage_robot.core import topics
from sage_robot.core.msgs import Text
from sage_robot.core.msgs.nav import NavigateFeedback, NavState

from ..support.waits import wait_until

pytestmark = pytest.mark.browser

WAIT_MS = 30_000
NAV_WAIT_MS = 60_000  # the real navigator plans across the building first
CAFE_TITLE = "Guelly Delly café"  # the knowledge base's title of GUELLY_DELLY


def open_face(browser: Any, robot: Any) -> Any:
    page = browser.new_page(viewport={"width": 1280, "height": 800})
    page.goto(f"{robot.url}/face")
    page.wait_for_selector("#link.up", timeout=WAIT_MS)
    return page


def test_idle_face_invites_to_talk_or_scan(browser: Any, robot: Any) -> None:
    page = open_face(browser, robot)
    try:
        attract = page.locator("#attract-text")
        attract.wait_for(state="visible", timeout=WAIT_MS)
        text = attract.text_content() or ""
        assert "Hey Jarvis" in text, text
        assert "scan me" in text, text
        page.wait_for_selector("#talk-qr:not([hidden])", timeout=WAIT_MS)
        assert page.locator("#guide").is_hidden()
        assert page.locator("main h1").count() == 1
        assert page.locator("#battery-wrap").is_hidden(), "a visitor sees the battery only when it is low"
        page.screenshot(path=str(robot.artifacts / "face-attract.png"))
    finally:
        page.close()


def test_typed_question_is_captioned_and_guiding_card_stops_the_walk(browser: Any, robot: Any) -> None:
    face = open_face(browser, robot)
    phone = browser.new_page(viewport={"width": 390, "height": 844}, is_mobile=True, has_touch=True)
    try:
        phone.goto(f"{robot.url}/talk")
        phone.fill("#question", "take me to the cafe")
        phone.click("button[type=submit]")
        face.wait_for_function(
            """[...document.querySelectorAll('#caption-log li.visitor')]
                 .some((li) => li.textContent.includes('take me to the cafe'))""",
            timeout=WAIT_MS,
        )
        face.wait_for_selector("#caption-log li.robot", timeout=WAIT_MS)  # the answer
        assert face.get_attribute("#caption-log", "aria-live") == "polite"
        face.wait_for_selector("#guide:not([hidden])", timeout=NAV_WAIT_MS)
        assert face.text_content("#guide-title") == CAFE_TITLE
        assert face.get_attribute("#guide-title", "title") == "GUELLY_DELLY"  # the code name: tooltip only
        assert face.locator("#attract-text").is_hidden(), "no invitation while guiding"
        face.screenshot(path=str(robot.artifacts / "face-guiding.png"))
        face.click("#guide-stop")
        wait_until(
            lambda: robot.call(lambda: robot.bus.actions.active(topics.NAVIGATE_TO)) is None,
            "the walk to be cancelled",
            15.0,
        )
        face.wait_for_function(
            "['canceled', 'idle'].includes(document.body.dataset.navState)", timeout=WAIT_MS
        )
    finally:
        phone.close()
        face.close()


def test_guiding_card_shows_distance_and_eta_and_announcements_are_captioned(
    browser: Any, robot: Any
) -> None:
    face = open_face(browser, robot)
    try:
        robot.publish(topics.NAV_STATE, NavigateFeedback(NavState.DRIVING, "HESSE_CENTER", 12.4, 20.0))
        face.wait_for_function(
            "document.getElementById('guide-title').textContent === 'Hesse Center'", timeout=WAIT_MS
        )
        assert face.text_content("#guide-progress") == "12 m to go · about 20 s"
        robot.publish(topics.NAV_STATE, NavigateFeedback(NavState.IDLE))
        face.wait_for_selector("#guide[hidden]", state="attached", timeout=WAIT_MS)
        robot.publish(topics.SAY, Text("Excuse me, could I get by?"))
        face.wait_for_function(
            """[...document.querySelectorAll('#caption-log li.announcement')]
                 .some((li) => li.textContent.includes('could I get by'))""",
            timeout=WAIT_MS,
        )
        robot.publish(topics.HEARD, Text("where are the restrooms"))
        face.wait_for_function(
            """[...document.querySelectorAll('#caption-log li.visitor')]
                 .some((li) => li.textContent.includes('where are the restrooms'))""",
            timeout=WAIT_MS,
        )
    finally:
        face.close()


def test_places_api_has_titles_and_robot_mic_is_sim_voice_only(robot: Any, cookie: str) -> None:
    with httpx.Client(base_url=robot.url, timeout=30.0, headers={"Cookie": cookie}) as c:
        places = c.get("/api/places").json()["places"]
        titles = {p["name"]: p["title"] for p in places}
        assert titles["GUELLY_DELLY"] == CAFE_TITLE
        assert titles["ECE_LAB_1"] == "ECE Lab 1"
        assert all(t and "_" not in t for t in titles.values()), titles
        # no voice node runs here: nothing listens on the simulated microphone
        assert c.get("/api/talk/robot_mic").json()["available"] is False
        resp = c.post(
            "/api/talk/robot_mic", json={"text": "where is the cafe"}, headers={"Origin": robot.url}
        )
        assert resp.status_code == 409, resp.text


def test_battery_shows_to_visitors_only_when_low(browser: Any, robot: Any) -> None:
    """The simulated battery is full (hidden from a visitor); the rule for a low one is checked
    in the page (the simulated bridge keeps publishing its own battery state)."""
    face = open_face(browser, robot)
    try:
        face.wait_for_function("document.getElementById('battery').textContent !== '—'", timeout=WAIT_MS)
        assert face.locator("#battery-wrap").is_hidden()
        low = face.evaluate("""import('/static/js/face.js').then((m) => [
            m.batteryLow({percentage: 12, is_charging: false}),
            m.batteryLow({percentage: 12, is_charging: true}),
            m.batteryLow({percentage: 80, is_charging: false}), m.batteryLow({percentage: null})])""")
        assert low == [True, False, False, False]
    finally:
        face.close()


def test_voice_reply_is_captioned_once_when_its_turn_ends(robot: Any) -> None:
    """The voice pipeline's reply (ui_state.llm_tokens) becomes one caption when the turn ends;
    an announcement spoken later, while ui_state still holds that reply, does not repeat it."""
    from sage_robot.core.msgs.voice import Phase, UiState

    hub = robot.web_node().hub
    reply = "The mechatronics lab is down the hall."

    def voice_captions() -> list[str]:
        return robot.call(lambda: [c["text"] for c in hub.captions if c["via"] == "voice"])

    robot.publish(topics.UI_STATE, UiState(Phase.LISTENING))
    robot.publish(topics.UI_STATE, UiState(Phase.THINKING, asr_final="where is mechatronics"))
    robot.publish(topics.UI_STATE, UiState(Phase.SPEAKING, llm_tokens=reply, tts_viseme=0.5))
    robot.publish(topics.UI_STATE, UiState(Phase.IDLE, llm_tokens=reply))
    wait_until(lambda: voice_captions().count(reply) == 1, "the reply's caption", 10.0)
    robot.publish(topics.UI_STATE, UiState(Phase.SPEAKING, llm_tokens=reply, tts_viseme=0.5))
    robot.publish(topics.UI_STATE, UiState(Phase.IDLE, llm_tokens=reply))
    robot.publish(topics.UI_STATE, UiState(Phase.LISTENING))  # the next turn (same topic: in order)
    robot.publish(topics.UI_STATE, UiState(Phase.SPEAKING, llm_tokens="Next one.", tts_viseme=0.5))
    robot.publish(topics.UI_STATE, UiState(Phase.IDLE, llm_tokens="Next one."))
    wait_until(lambda: "Next one." in voice_captions(), "the next turn's caption", 10.0)
    assert voice_captions().count(reply) == 1


def test_battery_shows_to_an_operator_logged_in_on_that_browser(browser: Any, robot: Any) -> None:
    context = browser.new_context(viewport={"width": 1280, "height": 800})
    try:
        resp = context.request.post(f"{robot.url}/api/login", data={"password": robot.password},
                                    headers={"Origin": robot.url})
        assert resp.ok, resp.text()
        face = context.new_page()
        face.goto(f"{robot.url}/face")
        face.wait_for_function("document.getElementById('battery').textContent !== '—'", timeout=WAIT_MS)
        face.wait_for_selector("#battery-wrap", state="visible", timeout=WAIT_MS)
        assert (face.text_content("#battery") or "").endswith("%")
    finally:
        context.close()
