"""/talk for every visitor, and the face while a phone's question is answered (issue #21), in real
Chromium against the real web server (a stand-in brain behind the ``converse`` action).

- Hold-to-talk works from the keyboard (Space or Enter held on the focused button) and as
  tap-to-toggle (a tap, a key press or a screen reader's click starts recording, the next one
  sends), not only as a held pointer.
- The reply and the page's state are in live regions (screen readers say them).
- A microphone the browser blocks for the site is said before any press; typing stays.
- While a ``/talk`` question is on its way, the kiosk face shows ``thinking``; the robot's own
  conversation (listening, thinking, speaking on ``/sage/ui_state``) is shown over it.

Recordings go to a routed ``/api/talk/audio`` that answers as the robot would (the real speech
to text path is ``test_phone_e2e.py``'s); Chromium's fake microphone records a beep.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from sage_robot.brain.base import Utterance
from sage_robot.core import topics
from sage_robot.core.actions import GoalContext
from sage_robot.core.msgs import Text
from sage_robot.core.msgs.voice import Phase, UiState

from .conftest import artifacts_dir
from .test_https import WebServer, web_server

pytestmark = pytest.mark.browser

WAIT_MS = 30_000
CALL_TIMEOUT_S = 10.0
RECORD_MS = 600  # how long the test speaks into a recording (the page sends from 300 ms)
PHONE = {"width": 390, "height": 844}
REPLY = "The cafe is on the first floor."
# Installed before the face's scripts: every phase the face shows, in order.
PHASE_LOG = """
window.phaseLog = [];
document.addEventListener("DOMContentLoaded", () => {
  new MutationObserver(() => {
    const phase = document.body.dataset.phase;
    if (window.phaseLog[window.phaseLog.length - 1] !== phase) window.phaseLog.push(phase);
  }).observe(document.body, { attributes: true, attributeFilter: ["data-phase"] });
});
"""


def on_loop(server: WebServer, fn: Callable[[], Any]) -> Any:
    """``fn()`` on the server's event loop thread; its value."""
    fut: concurrent.futures.Future[Any] = concurrent.futures.Future()

    def inner() -> None:
        try:
            fut.set_result(fn())
        except BaseException as exc:
            fut.set_exception(exc)

    server.loop.call_soon_threadsafe(inner)
    return fut.result(CALL_TIMEOUT_S)


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[WebServer]:
    """The web server on loopback over plain http (a secure context: the microphone works).
    The tests share it and its per-address question limit, which is not what they test
    (``test_phone_e2e.py`` does): a generous one, or on a fast machine the module's requests
    spend the burst and the last test's typed question is answered 429."""
    with web_server(tmp_path_factory.mktemp("talk-access"), {"tls": "off", "talk_per_min": 600.0}) as s:
        yield s


def url(server: WebServer, path: str) -> str:
    return f"http://127.0.0.1:{server.node.port}{path}"


@pytest.fixture
def phone(browser: Any) -> Iterator[Any]:
    ctx = browser.new_context(viewport=PHONE, has_touch=True, is_mobile=True, permissions=["microphone"])
    try:
        yield ctx
    finally:
        ctx.close()


def open_talk(ctx: Any, server: WebServer) -> tuple[Any, list[str]]:
    """/talk with its recordings answered as the robot would; the uploads' content types."""
    uploads: list[str] = []

    def robot_answers(route: Any) -> None:
        uploads.append(route.request.headers.get("content-type", ""))
        route.fulfill(json={"transcript": "where is the cafe", "reply": REPLY})

    page = ctx.new_page()
    page.route("**/api/talk/audio", robot_answers)
    page.goto(url(server, "/talk"))
    page.wait_for_function("document.body.dataset.mic === 'available'", timeout=WAIT_MS)
    return page, uploads


def recorded_a_while(page: Any) -> None:
    """Wait until the button records, then until RECORD_MS have passed in the page."""
    page.wait_for_selector("#ptt.recording", timeout=WAIT_MS)
    since = page.evaluate("performance.now()")
    page.wait_for_function(f"performance.now() > {since + RECORD_MS}", timeout=WAIT_MS)


def replied(page: Any, n: int = 1) -> None:
    page.wait_for_function(f"Number(document.body.dataset.replies || 0) >= {n}", timeout=WAIT_MS)


def test_space_held_on_the_button_records_until_released(phone: Any, server: WebServer) -> None:
    page, uploads = open_talk(phone, server)
    page.focus("#ptt")
    page.keyboard.down("Space")
    recorded_a_while(page)
    assert page.get_attribute("#ptt", "aria-pressed") == "true"
    assert "release to send" in (page.text_content("#ptt") or "")
    assert uploads == [], "nothing is sent while the key is held"
    page.keyboard.up("Space")
    replied(page)
    assert len(uploads) == 1
    assert uploads[0].startswith("multipart/form-data")
    assert page.get_attribute("#ptt", "aria-pressed") == "false"
    assert page.text_content("#ptt") == "Hold to talk"
    # the reply is in a live region: a screen reader says it
    log = page.locator("#conversation")
    assert log.get_attribute("role") == "log"
    assert log.get_attribute("aria-live") == "polite"
    assert REPLY in (log.inner_text() or "")
    assert page.get_attribute("#status", "aria-live") == "polite"
    assert page.get_attribute("#status", "role") == "status"


def test_enter_tapped_starts_recording_and_tapped_again_sends(phone: Any, server: WebServer) -> None:
    page, uploads = open_talk(phone, server)
    page.focus("#ptt")
    page.keyboard.press("Enter")  # a tap: down and up at once
    recorded_a_while(page)
    assert page.get_attribute("body", "data-ptt") == "toggle", "a tap keeps recording"
    assert "tap to send" in (page.text_content("#ptt") or "")
    assert page.get_attribute("#ptt", "aria-pressed") == "true"
    assert uploads == []
    page.keyboard.press("Enter")
    replied(page)
    assert len(uploads) == 1
    assert page.get_attribute("body", "data-ptt") == "off"


def test_finger_tap_and_screen_reader_click_toggle_recording(phone: Any, server: WebServer) -> None:
    page, uploads = open_talk(phone, server)
    page.locator("#ptt").tap()  # touch: pointerdown and pointerup of a finger
    recorded_a_while(page)
    assert page.get_attribute("body", "data-ptt") == "toggle"
    page.locator("#ptt").tap()
    replied(page, 1)
    assert len(uploads) == 1
    # a screen reader activates the button with a click that no pointer or key made
    page.evaluate("document.getElementById('ptt').click()")
    recorded_a_while(page)
    assert page.get_attribute("body", "data-ptt") == "toggle"
    page.evaluate("document.getElementById('ptt').click()")
    replied(page, 2)
    assert len(uploads) == 2
    page.screenshot(path=str(Path(artifacts_dir()) / "talk-tap-to-toggle.png"))


def test_a_talk_question_makes_the_face_think(browser: Any, phone: Any, server: WebServer) -> None:
    """The face is ``thinking`` from the question to the reply; the robot's own voice turn, were
    one to start meanwhile, shows over it; then the face rests again."""
    bus = server.ctx.bus
    gate = asyncio.Event()
    asked: list[str] = []

    async def slow_brain(goal: Text | Utterance, ctx: GoalContext) -> Text:
        asked.append(goal.data if isinstance(goal, Text) else goal.text)
        await gate.wait()
        return Text(REPLY)

    stand_in = on_loop(server, lambda: bus.actions.unserve(topics.CONVERSE))
    on_loop(server, lambda: bus.actions.serve(topics.CONVERSE, slow_brain))
    face = browser.new_page(viewport={"width": 1280, "height": 800})
    try:
        face.add_init_script(PHASE_LOG)
        face.goto(url(server, "/face"))
        face.wait_for_selector("#link.up", timeout=WAIT_MS)
        assert face.get_attribute("body", "data-phase") == "idle"
        page, _ = open_talk(phone, server)
        page.fill("#question", "where is the cafe")
        page.click("#ask-btn")
        face.wait_for_selector("body[data-phase=thinking]", timeout=WAIT_MS)
        assert face.text_content("#phase") == "thinking"  # in the status corner (a live region)
        assert face.get_attribute(".corner", "role") == "status"
        assert asked == ["where is the cafe"]
        face.screenshot(path=str(artifacts_dir() / "face-thinking-talk.png"))
        on_loop(server, lambda: bus.publish(topics.UI_STATE, UiState(Phase.LISTENING)))
        face.wait_for_selector("body[data-phase=listening]", timeout=WAIT_MS)
        on_loop(server, lambda: bus.publish(topics.UI_STATE, UiState(Phase.IDLE)))
        face.wait_for_selector("body[data-phase=thinking]", timeout=WAIT_MS)
        server.loop.call_soon_threadsafe(gate.set)
        replied(page)
        face.wait_for_selector("body[data-phase=idle]", timeout=WAIT_MS)
        log = face.evaluate("window.phaseLog")  # after the resting state it may have been sent first
        assert log[log.index("thinking"):] == ["thinking", "listening", "thinking", "idle"], log
        face.wait_for_function(
            """[...document.querySelectorAll('#caption-log li.robot')]
                 .some((li) => li.textContent.includes('first floor'))""",
            timeout=WAIT_MS,
        )
    finally:
        face.close()
        on_loop(server, lambda: bus.actions.unserve(topics.CONVERSE))
        on_loop(server, lambda: bus.actions.serve(topics.CONVERSE, stand_in.handler))


# What the browser's Permissions API answers about the microphone, as after a visitor said no once
# (Chromium's own prompt is bypassed in the tests: --use-fake-ui-for-media-stream).
MIC_DENIED = """
(() => {
  const query = navigator.permissions.query.bind(navigator.permissions);
  window.micPermission = { state: "denied", onchange: null };
  navigator.permissions.query = (d) =>
    (d.name === "microphone" ? Promise.resolve(window.micPermission) : query(d));
})();
"""


def test_blocked_microphone_is_said_before_any_press_and_typing_stays(phone: Any, server: WebServer) -> None:
    phone.add_init_script(MIC_DENIED)
    page = phone.new_page()
    page.goto(url(server, "/talk"))
    page.wait_for_function("document.body.dataset.mic === 'blocked'", timeout=WAIT_MS)
    assert page.is_visible("#mic-note")
    assert "blocks the microphone" in (page.inner_text("#mic-note") or "")
    assert "type instead" in (page.inner_text("#mic-note") or "")
    assert page.is_hidden("#ptt")
    page.fill("#question", "where is the cafe?")
    page.click("#ask-btn")
    replied(page)
    # allowed in the site settings: the button comes back
    page.evaluate("window.micPermission.state = 'granted'; window.micPermission.onchange()")
    page.wait_for_function("document.body.dataset.mic === 'available'", timeout=WAIT_MS)
    assert page.is_visible("#ptt")
    assert page.is_hidden("#mic-note")
