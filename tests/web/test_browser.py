"""Every page in a real Chromium (Playwright) against the web node on the simulator.

The robot moves because the page's key presses travel /ws/teleop -> /cmd_vel -> the real
serial bridge -> CMD frames on a pty -> the firmware model -> ODOM frames -> /odom.
Screenshots land in $SAGE_ARTIFACTS/web (default /tmp/sage-artifacts/web).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

from sage_robot.core import topics
from sage_robot.core.msgs.voice import AudioChunk, Doa, Phase, UiState
from sage_robot.core.places import load_places

from ..support.waits import wait_until as _wait_until

# Real Chromium against the simulator running in real time. Every wait is on a condition (in
# the page: wait_for_selector/wait_for_function; on the robot: wait_until) bounded generously:
# a busy machine slows the simulated robot and the page down, which must not fail a test (one
# CI run of four once timed out waiting 8 s for the joystick to drive). Durations that are the
# test ("the robot stays still for 1 s") are counted on the robot's simulated clock.
pytestmark = pytest.mark.browser

WAIT_S = 30.0  # bound on any condition below (a quiet machine takes a small part of it)
MOVED_M = 0.05  # farther than this counts as "the robot moved"
STILL_MPS = 0.01  # slower than this counts as stopped
NAV_WAIT_S = 60.0  # the real navigator plans across the building before it drives
CAMERA_SHOWN = "document.getElementById('camera').src.startsWith('blob:')"  # a JPEG frame arrived
QUIET_SOCKETS = ("/ws/doa", "/ws/audio")  # these send only when something is published

# Counts each WebSocket's messages, so a test can wait for a page's first round of data.
SOCKET_PROBE = """
(() => {
  const Native = window.WebSocket;
  window.sageSockets = [];
  window.WebSocket = class extends Native {
    constructor(...args) {
      super(...args);
      const s = { url: String(args[0]), open: false, messages: 0 };
      window.sageSockets.push(s);
      this.addEventListener("open", () => { s.open = true; });
      this.addEventListener("message", () => { s.messages += 1; });
    }
  };
})();
"""
# Records the events that end a drive on the page (drive.js lets go on each), so a timeout can say
# whether the page let go and why.
RELEASE_PROBE = """
(() => {
  window.sageReleases = [];
  const note = (e) => window.sageReleases.push(
    `${e.type}@${Math.round(performance.now())}ms on ${e.target && (e.target.id || e.target.nodeName)}`);
  for (const type of ["blur", "pointerup", "pointercancel", "lostpointercapture", "visibilitychange"]) {
    window.addEventListener(type, note, true);
  }
})();
"""
FIRST_ROUND = f"""window.sageSockets.every(
    (s) => s.open && (s.messages > 0 || {list(QUIET_SOCKETS)!r}.some((p) => s.url.endsWith(p))))"""


def wait_until(cond: Any, what: str, timeout: float = WAIT_S, robot: Any = None, page: Any = None) -> Any:
    """A bounded wait; with ``robot``, a timeout also says what teleop and the robot were doing (and
    with ``page``, which of the events that end a drive the page saw)."""
    detail = None if robot is None else (lambda: drive_state(robot, page))
    return _wait_until(cond, what, timeout, poll=0.05, detail=detail)


def drive_state(robot: Any, page: Any = None) -> str:
    teleop = robot.web_node().teleop
    odom = robot.odom
    moving = "no odometry" if odom is None else f"v={odom.twist.linear_x:.3f} w={odom.twist.angular_z:.3f}"
    state = (f"sim t={robot.ctx.clock.now():.2f}; teleop command={teleop.command} counts={teleop.counts}; "
             f"{moving}")
    if page is not None:
        state += f"; the page's release events: {page.evaluate('window.sageReleases')}"
    return state


def sim_seconds(robot: Any, seconds: float) -> None:
    """Let ``seconds`` of the robot's simulated time pass (however long that takes here)."""
    clock = robot.ctx.clock
    t_end = clock.now() + seconds
    wait_until(lambda: clock.now() >= t_end, f"{seconds} simulated s to pass", robot=robot)


def odom_xy(robot: Any) -> tuple[float, float]:
    assert robot.odom is not None, "no odometry from the simulated MCU"
    return robot.odom.pose.x, robot.odom.pose.y


def moved_from(robot: Any, start: tuple[float, float]) -> float:
    x, y = odom_xy(robot)
    return math.hypot(x - start[0], y - start[1])


def stopped(robot: Any) -> bool:
    return robot.odom is not None and abs(robot.odom.twist.linear_x) < STILL_MPS


class Console:
    """Collects console errors and uncaught exceptions of a page."""

    def __init__(self, page: Any) -> None:
        self.errors: list[str] = []
        page.on("console", lambda m: self.errors.append(m.text) if m.type == "error" else None)
        page.on("pageerror", lambda e: self.errors.append(f"uncaught: {e}"))


@pytest.fixture(scope="module")
def operator(browser: Any, robot: Any) -> Iterator[Any]:
    """A browser context logged in through the login page."""
    context = browser.new_context(viewport={"width": 1280, "height": 900})
    page = context.new_page()
    page.goto(f"{robot.url}/teleop")
    assert "/login" in page.url, "the teleop page must ask for the login first"
    page.fill("#password", robot.password)
    page.click("button[type=submit]")
    page.wait_for_url(f"{robot.url}/teleop", timeout=WAIT_S * 1000)
    page.close()
    yield context
    context.close()


def open_teleop(operator: Any, robot: Any) -> tuple[Any, Console]:
    page = operator.new_page()
    page.add_init_script(RELEASE_PROBE)
    console = Console(page)
    page.goto(f"{robot.url}/teleop")
    page.wait_for_selector("#link.up", timeout=WAIT_S * 1000)
    return page, console


def test_every_page_loads_without_console_errors(operator: Any, robot: Any) -> None:
    checks = {
        "/": "#nodes tr",
        "/teleop": "#map[data-map-version]",
        "/face": "#mouth",
        "/talk": "#ptt",
        "/admin": "#nodes tr",
    }
    for path, selector in checks.items():
        page = operator.new_page()
        page.add_init_script(SOCKET_PROBE)
        console = Console(page)
        page.goto(f"{robot.url}{path}")
        page.wait_for_selector(selector, timeout=WAIT_S * 1000, state="attached")
        if path == "/teleop":  # the simulated camera's JPEG frames arrive over /ws/camera
            page.wait_for_function(CAMERA_SHOWN, timeout=WAIT_S * 1000)
        page.wait_for_function(FIRST_ROUND, timeout=WAIT_S * 1000)  # the sockets' first round arrived
        name = path.strip("/") or "index"
        page.screenshot(path=str(robot.artifacts / f"{name}.png"))
        page.close()
        assert console.errors == [], f"{path}: console errors {console.errors}"
    assert "web" in robot.node_names


def camera_subscribers(robot: Any) -> int:
    def count() -> int:
        info = robot.bus.topics().get(topics.CAMERA)
        return len(info.subscribers) if info is not None else 0

    return int(robot.call(count))


def test_camera_is_subscribed_only_while_a_page_shows_it(operator: Any, robot: Any) -> None:
    """The simulator renders frames only for a subscriber: the web subscribes while a page
    shows the video and lets go when the last one closes."""
    wait_until(lambda: camera_subscribers(robot) == 0, what="no camera subscription without a viewer")
    hub = robot.web_node().hub
    page, console = open_teleop(operator, robot)
    page.wait_for_function(CAMERA_SHOWN, timeout=WAIT_S * 1000)
    assert camera_subscribers(robot) == 1
    second, _ = open_teleop(operator, robot)  # two viewers share one subscription
    second.wait_for_function(CAMERA_SHOWN, timeout=WAIT_S * 1000)
    assert camera_subscribers(robot) == 1
    second.close()
    wait_until(lambda: robot.call(lambda: hub.camera_viewers) == 1, "the web to see the second viewer go")
    assert camera_subscribers(robot) == 1, "the first page still shows the video"
    page.close()
    wait_until(lambda: camera_subscribers(robot) == 0, what="the camera unsubscribed after the page closed")
    assert console.errors == []


# Holds /ws/camera's frames back until the test calls window.sageShowCamera().
CAMERA_GATE = """
(() => {
  const Native = window.WebSocket;
  let open = false;
  const held = [];
  window.sageShowCamera = () => { open = true; held.splice(0).forEach((f) => f()); };
  window.WebSocket = class extends Native {
    constructor(...args) {
      super(...args);
      if (!String(args[0]).endsWith("/ws/camera")) return;
      const gate = (fn) => (e) => (open ? fn(e) : held.push(() => fn(e)));
      const native = Object.getOwnPropertyDescriptor(Native.prototype, "onmessage");
      Object.defineProperty(this, "onmessage", { set: (fn) => native.set.call(this, gate(fn)) });
      const add = this.addEventListener.bind(this);
      this.addEventListener = (type, fn, ...rest) => add(type, type === "message" ? gate(fn) : fn, ...rest);
    }
  };
})();
"""


def test_the_drive_controls_stay_put_when_the_video_starts(operator: Any, robot: Any) -> None:
    """An operator's finger or mouse is often already on the joystick when the first camera frame
    arrives: nothing on the page may move under it then (it once jumped the height of the video,
    and a pressed joystick became a drag of the video that let go of the robot)."""
    page = operator.new_page()
    page.add_init_script(CAMERA_GATE)
    console = Console(page)
    page.goto(f"{robot.url}/teleop")
    page.wait_for_selector("#link.up", timeout=WAIT_S * 1000)
    controls = ("#joystick", "#throttle", "#brake", "#wheel", "#estop")
    before = {c: page.locator(c).bounding_box() for c in controls}
    assert page.evaluate(CAMERA_SHOWN) is False, "the gate let a frame through"
    page.evaluate("window.sageShowCamera()")
    page.wait_for_function(CAMERA_SHOWN, timeout=WAIT_S * 1000)
    page.wait_for_function("document.getElementById('camera-note').textContent === ''",
                           timeout=WAIT_S * 1000)
    after = {c: page.locator(c).bounding_box() for c in controls}
    assert after == before, f"controls moved when the video started: {before} -> {after}"
    assert page.get_attribute("#camera", "draggable") == "false"
    page.close()
    assert console.errors == []


def test_holding_arrow_up_drives_and_releasing_stops(operator: Any, robot: Any) -> None:
    page, console = open_teleop(operator, robot)
    wait_until(lambda: robot.odom is not None and stopped(robot), what="a still robot", robot=robot)
    start = odom_xy(robot)
    page.keyboard.down("ArrowUp")
    try:
        wait_until(lambda: moved_from(robot, start) > MOVED_M, what="odometry to change", robot=robot)
        assert robot.odom is not None
        assert robot.odom.twist.linear_x > 0.05
        page.screenshot(path=str(robot.artifacts / "teleop-driving.png"))
    finally:
        page.keyboard.up("ArrowUp")
    wait_until(lambda: stopped(robot), what="the robot to stop after release", robot=robot)
    rest = odom_xy(robot)
    sim_seconds(robot, 0.5)  # the test: it stays still
    assert moved_from(robot, rest) < 0.02, "the robot kept moving after the key was released"
    page.close()
    assert console.errors == []


def test_joystick_pedal_and_wheel_drive_and_stop(operator: Any, robot: Any) -> None:
    page, console = open_teleop(operator, robot)
    for selector in ("#joystick", "#throttle"):
        wait_until(lambda: stopped(robot), what="a still robot", robot=robot)
        start = odom_xy(robot)
        box = page.locator(selector).bounding_box()
        assert box is not None
        cx, cy = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
        page.mouse.move(cx, cy)
        page.mouse.down()
        if selector == "#joystick":
            page.mouse.move(cx, cy - box["height"] * 0.4, steps=4)  # push forward
        wait_until(lambda s=start: moved_from(robot, s) > MOVED_M, what=f"{selector} to drive", robot=robot,
                   page=page)
        page.mouse.up()
        wait_until(lambda: stopped(robot), what=f"the robot to stop after releasing {selector}", robot=robot)
    # the steering wheel turned a quarter to the right turns the robot clockwise in place
    assert robot.odom is not None
    heading = robot.odom.pose.theta
    box = page.locator("#wheel").bounding_box()
    assert box is not None
    cx, cy = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
    page.mouse.move(cx, box["y"] + 5)
    page.mouse.down()
    page.mouse.move(cx + box["width"] / 2 - 5, cy, steps=6)
    turned = wait_until(
        lambda: robot.odom is not None
        and math.remainder(robot.odom.pose.theta - heading, 2 * math.pi) < -0.1,
        what="the wheel to turn the robot",
        robot=robot,
    )
    page.mouse.up()
    assert turned
    wait_until(lambda: robot.odom is not None and abs(robot.odom.twist.angular_z) < 0.02, what="a stop",
               robot=robot)
    page.close()
    assert console.errors == []


def test_closing_the_page_while_driving_stops_the_robot(operator: Any, robot: Any) -> None:
    page, _ = open_teleop(operator, robot)
    teleop = robot.web_node().teleop
    stops_before = teleop.counts["close_stops"] + teleop.counts["deadman_stops"]
    start = odom_xy(robot)
    page.keyboard.down("ArrowUp")
    wait_until(lambda: moved_from(robot, start) > MOVED_M, what="the robot to drive", robot=robot)
    # The tab's renderer dies with the key held: no keyup, no blur, no goodbye on the socket (a
    # plain close lets the page send its stop on `blur` first, and then the server has nothing to
    # do). Only the server can stop the robot now.
    with pytest.raises(Exception, match="crash"):
        page.goto("chrome://crash")
    wait_until(lambda: stopped(robot), what="the robot to stop after the page died", robot=robot)
    assert teleop.counts["close_stops"] + teleop.counts["deadman_stops"] > stops_before
    page.close()


def test_estop_blocks_driving_until_released_on_purpose(operator: Any, robot: Any) -> None:
    page, console = open_teleop(operator, robot)
    try:
        page.click("#estop")
        page.wait_for_selector("body[data-estop=true]", timeout=WAIT_S * 1000)
        wait_until(lambda: stopped(robot), what="a still robot", robot=robot)
        start = odom_xy(robot)
        page.keyboard.down("ArrowUp")
        # the server refuses the held key's commands, and the robot stays still while it is held
        page.wait_for_function("document.getElementById('teleop-error').textContent.includes('e-stop')",
                               timeout=WAIT_S * 1000)
        sim_seconds(robot, 1.0)  # the test: still for a second of held key
        page.keyboard.up("ArrowUp")
        assert moved_from(robot, start) < 0.02, "the robot moved with the e-stop engaged"
        page.screenshot(path=str(robot.artifacts / "teleop-estop.png"))
        page.click("#release")  # one click is not enough: it asks for a confirmation
        page.wait_for_selector("#confirm-release", state="visible", timeout=WAIT_S * 1000)
        assert page.get_attribute("body", "data-estop") == "true"
        assert robot.web_node().teleop.estop
        page.click("#confirm-release")
        page.wait_for_selector("body[data-estop=false]", timeout=WAIT_S * 1000)
        page.keyboard.down("ArrowUp")
        wait_until(lambda: moved_from(robot, start) > MOVED_M, what="driving after the release", robot=robot)
        page.keyboard.up("ArrowUp")
        wait_until(lambda: stopped(robot), what="the robot to stop", robot=robot)
    finally:
        robot.run(robot.web_node().teleop.set_estop(False, "test cleanup"))
        page.close()
    assert console.errors == []


def test_click_on_the_map_sends_a_goal_and_the_robot_moves(operator: Any, robot: Any) -> None:
    """Uses the real navigator when registered; otherwise the test's navigate_to server
    (which drives straight while its goal runs) — ``robot.stand_ins`` says which."""
    page, console = open_teleop(operator, robot)
    page.wait_for_selector("#map[data-map-version]", timeout=WAIT_S * 1000)
    wait_until(lambda: stopped(robot), what="a still robot", robot=robot)
    start = odom_xy(robot)
    goals_before = len(robot.goals)
    page.locator("#map").scroll_into_view_if_needed()
    box = page.locator("#map").bounding_box()
    assert box is not None
    page.mouse.click(box["x"] + box["width"] * 0.75, box["y"] + box["height"] * 0.5)
    if "navigate_to" in robot.stand_ins:
        wait_until(lambda: len(robot.goals) > goals_before, what="a navigate_to goal")
        goal = robot.goals[-1]
        assert goal.pose is not None
        assert goal.place == ""
        assert goal.pose.x > 0.5, f"the click right of centre should be at +x, got {goal.pose}"
    wait_until(lambda: moved_from(robot, start) > MOVED_M, what="the robot to start moving", robot=robot)
    page.wait_for_function("document.querySelector('#nav').textContent.length > 2")
    page.screenshot(path=str(robot.artifacts / "teleop-goal.png"))
    page.click("#cancel")
    wait_until(lambda: stopped(robot), what="the robot to stop after cancel", robot=robot)
    page.close()
    assert console.errors == []


def test_drag_on_the_map_sets_the_initial_pose(operator: Any, robot: Any) -> None:
    from sage_robot.core.msgs import PoseWithCovariance

    got: list[PoseWithCovariance] = []
    sub = robot.call(lambda: robot.bus.subscribe(topics.INITIAL_POSE, PoseWithCovariance, got.append))
    page, console = open_teleop(operator, robot)
    page.wait_for_selector("#map[data-map-version]", timeout=WAIT_S * 1000)
    pose = wait_until(lambda: robot.web_node().hub.robot_pose, what="the robot's pose")
    box = page.locator("#map").bounding_box()
    assert box is not None
    # drag from where the robot is, along its heading: localization stays where it was
    x, y, theta = pose
    ahead = (x + 3.0 * math.cos(theta), y + 3.0 * math.sin(theta))
    p0 = page.evaluate(f"window.sageMap.toPx({x}, {y})")
    p1 = page.evaluate(f"window.sageMap.toPx({ahead[0]}, {ahead[1]})")
    page.check("input[name=tool][value=pose]")  # "go here" is the default tool: a drag there is a goal
    page.mouse.move(box["x"] + p0[0], box["y"] + p0[1])
    page.mouse.down()
    page.mouse.move(box["x"] + p1[0], box["y"] + p1[1], steps=5)
    page.mouse.up()
    page.wait_for_selector("#pose-confirm:not([hidden])", timeout=WAIT_S * 1000)
    sim_seconds(robot, 0.3)
    assert not got, "a drag must not set the pose before the operator confirms"
    page.click("#pose-yes")
    wait_until(lambda: got, what="an /initialpose message")
    robot.call(sub.close)
    msg = got[-1]
    assert msg.frame_id == "map"
    assert math.hypot(msg.pose.x - x, msg.pose.y - y) < 0.5
    assert abs(math.remainder(msg.pose.theta - theta, 2 * math.pi)) < 0.2
    page.close()
    assert console.errors == []


def test_place_button_sends_a_named_goal(operator: Any, robot: Any) -> None:
    page, _ = open_teleop(operator, robot)
    page.click("#places button[data-place=DOCKING_STATION]")
    if "navigate_to" in robot.stand_ins:
        wait_until(lambda: robot.goals and robot.goals[-1].place == "DOCKING_STATION", what="a named goal")
    page.click("#cancel")
    wait_until(lambda: stopped(robot), what="the robot to stop after cancel", robot=robot)
    page.close()


def test_teleop_shows_navigation_started_by_anyone(operator: Any, robot: Any) -> None:
    """/nav/state reaches the operator whoever sent the goal: first a publisher of the
    test's own, then a goal sent on the bus as the brain sends a visitor's "take me to..."."""
    from sage_robot.core.msgs.nav import NavigateFeedback, NavigateGoal, NavState

    page, console = open_teleop(operator, robot)
    robot.publish(topics.NAV_STATE, NavigateFeedback(NavState.DRIVING, "CAFE", 39.5, 41.0))
    page.wait_for_function("document.getElementById('nav').textContent.includes('CAFE')")
    assert page.text_content("#nav") == "driving → CAFE · 39.5 m left · ETA 41 s"
    robot.publish(topics.NAV_STATE, NavigateFeedback(NavState.IDLE))
    page.wait_for_function("document.getElementById('nav').textContent === 'idle'")
    if "navigate_to" in robot.stand_ins:  # the test's server does not publish /nav/state
        page.close()
        return
    handle = robot.run(robot.bus.actions.send_goal(topics.NAVIGATE_TO, NavigateGoal(place="HESSE_CENTER")))
    try:
        page.wait_for_function(
            "document.getElementById('nav').title === 'HESSE_CENTER'"
            " && /Hesse Center · [0-9.]+ m left/.test(document.getElementById('nav').textContent)",
            timeout=NAV_WAIT_S * 1000,
        )
        page.screenshot(path=str(robot.artifacts / "teleop-visitor-goal.png"))
    finally:
        robot.run(handle.cancel())
    page.wait_for_function("document.getElementById('nav').textContent.startsWith('canceled')")
    assert "navigation: canceled → Hesse Center" in (page.text_content("#events") or "")  # the title
    # the ended goal's plan and marker leave the map (they would read as "still going")
    page.wait_for_function("window.sageMap.layers.goal === null && window.sageMap.layers.plan.length === 0")
    page.close()
    assert console.errors == []


def test_face_follows_ui_state_and_doa(browser: Any, robot: Any) -> None:
    page = browser.new_page(viewport={"width": 1024, "height": 768})
    console = Console(page)
    page.goto(f"{robot.url}/face")
    page.wait_for_selector("#link.up", timeout=WAIT_S * 1000)
    robot.publish(topics.UI_STATE, UiState(Phase.LISTENING, asr_partial="where is the"))
    page.wait_for_selector("body[data-phase=listening]", timeout=WAIT_S * 1000)
    robot.publish(topics.DOA, Doa(0.0, 90.0))  # speaker on the robot's left
    page.wait_for_function("Number(document.body.dataset.pupilX) > 10")
    left = float(page.get_attribute("body", "data-pupil-x") or "nan")
    robot.publish(topics.DOA, Doa(0.0, 270.0))  # on its right
    page.wait_for_function("Number(document.body.dataset.pupilX) < -10")
    right = float(page.get_attribute("body", "data-pupil-x") or "nan")
    assert left > 0 > right
    robot.publish(
        topics.UI_STATE,
        UiState(Phase.SPEAKING, asr_final="where is the lab?", llm_tokens="Follow me!", tts_viseme=1.0),
    )
    page.wait_for_selector("body[data-phase=speaking]", timeout=WAIT_S * 1000)
    page.wait_for_function("Number(document.getElementById('mouth').getAttribute('ry')) > 30")
    assert page.text_content("#reply") == "Follow me!"
    assert page.text_content("#heard") == "where is the lab?"
    page.screenshot(path=str(robot.artifacts / "face-speaking.png"))
    # the kiosk reconnects by itself: drop every connection server-side (as a restart would)
    def drop_all() -> None:
        for conn in list(robot.web_node().server.server_state.connections):
            conn.shutdown()

    robot.call(drop_all)
    page.wait_for_selector("#link:not(.up)", timeout=WAIT_S * 1000)
    page.wait_for_selector("#link.up", timeout=WAIT_S * 1000)
    robot.publish(topics.UI_STATE, UiState(Phase.THINKING))
    page.wait_for_selector("body[data-phase=thinking]", timeout=WAIT_S * 1000)
    # in simulation the kiosk plays the robot's voice: 0.1 s chunks of a 440 Hz tone
    t = np.arange(1600) / 16000.0
    tone = (0.3 * 32767 * np.sin(2 * np.pi * 440.0 * t)).astype("<i2").tobytes()
    for i in range(3):
        robot.publish(topics.AUDIO_OUT, AudioChunk(0.0, 16000, tone, 0.5, 1, final=i == 2))
    page.wait_for_function("Number(document.body.dataset.audioChunks) >= 3")
    page.close()
    assert console.errors == []


def test_talk_typed_question_gets_a_reply(browser: Any, robot: Any) -> None:
    page = browser.new_page(viewport={"width": 390, "height": 844}, is_mobile=True, has_touch=True)
    console = Console(page)
    page.goto(f"{robot.url}/talk")
    assert "take you" in (page.text_content(".hint") or ""), "the visitor is told what to do"
    page.fill("#question", "What is your name?")
    page.click("button[type=submit]")
    page.wait_for_selector(".bubble.sage", timeout=WAIT_S * 1000)
    reply = page.text_content(".bubble.sage") or ""
    assert page.text_content(".bubble.you") == "What is your name?"
    if "converse" in robot.stand_ins:  # the test's converse server
        assert "first floor" in reply
        assert "What is your name?" in robot.questions
    else:  # the real brain (offline without an LLM endpoint)
        assert robot.ctx.settings.robot.name in reply
    page.screenshot(path=str(robot.artifacts / "talk-reply.png"))
    page.close()
    assert [e for e in console.errors if "/api/talk/say" not in e] == []


def test_talk_hold_to_talk_records_and_uploads(browser: Any, robot: Any) -> None:
    """Chromium's fake microphone (a beep) -> MediaRecorder WebM -> /api/talk/audio -> ffmpeg
    -> speech to text. A beep holds no words, so the page says it heard none."""
    context = browser.new_context(viewport={"width": 390, "height": 844}, permissions=["microphone"])
    page = context.new_page()
    console = Console(page)
    page.goto(f"{robot.url}/talk")
    ptt = page.locator("#ptt").bounding_box()
    assert ptt is not None
    page.mouse.move(ptt["x"] + ptt["width"] / 2, ptt["y"] + ptt["height"] / 2)
    page.mouse.down()
    page.wait_for_selector("#ptt.recording", timeout=WAIT_S * 1000)
    page.wait_for_timeout(1500)  # the test: the button held for 1.5 s of recording
    page.mouse.up()
    page.wait_for_function(
        "document.getElementById('status').textContent.includes('did not hear')"
        " || document.querySelector('.bubble.you') !== null",
        timeout=2 * WAIT_S * 1000,  # ffmpeg and speech to text on a busy machine
    )
    status = page.text_content("#status") or ""
    assert "did not hear" in status or page.locator(".bubble.you").count() == 1, status
    context.close()
    assert console.errors == []


def test_operator_pages_refuse_a_visitor(browser: Any, robot: Any) -> None:
    context = browser.new_context()
    page = context.new_page()
    for path in ("/teleop", "/admin"):
        page.goto(f"{robot.url}{path}")
        assert "/login" in page.url
    page.goto(f"{robot.url}/login")
    page.fill("#password", "not the password")
    page.click("button[type=submit]")
    page.wait_for_function("document.getElementById('message').textContent.length > 0")
    assert "wrong password" in (page.text_content("#message") or "")
    # a visitor's page script cannot drive: the teleop socket refuses the handshake
    refused = page.evaluate(
        """() => new Promise((done) => {
            const ws = new WebSocket(`ws://${location.host}/ws/teleop`);
            ws.onopen = () => done("open");
            ws.onclose = () => done("refused");
        })"""
    )
    assert refused == "refused"
    context.close()


def test_admin_adds_a_place_by_clicking_the_map(operator: Any, robot: Any) -> None:
    teleop, _ = open_teleop(operator, robot)  # open meanwhile: its place buttons follow
    teleop.wait_for_selector("#places button", timeout=WAIT_S * 1000)
    page = operator.new_page()
    console = Console(page)
    page.goto(f"{robot.url}/admin")
    page.wait_for_selector("#map[data-map-version]", timeout=WAIT_S * 1000)
    # the panels above the map fill in asynchronously: measure the map once they have
    page.wait_for_selector("#places tr", timeout=WAIT_S * 1000)
    page.wait_for_function("!document.getElementById('kb').textContent.includes('loading')")
    page.locator("#map").scroll_into_view_if_needed()
    box = page.locator("#map").bounding_box()
    assert box is not None
    # click where a known place stands (a free cell by construction of the waypoints file)
    target = next(iter(load_places(robot.tmp / "waypoints.yaml"))).pose
    px, py = page.evaluate(f"window.sageMap.toPx({target.x}, {target.y})")
    page.mouse.click(box["x"] + px, box["y"] + py)
    assert abs(float(page.input_value("#p-x")) - target.x) < 0.3
    assert abs(float(page.input_value("#p-y")) - target.y) < 0.3
    page.fill("#p-name", "ATRIUM")
    page.fill("#p-desc", "the bright middle of the room")
    page.fill("#p-aliases", "the atrium, middle")
    page.click("#add-at-point")
    page.wait_for_function("document.getElementById('place-msg').textContent.length > 0")
    assert "added ATRIUM" in (page.text_content("#place-msg") or ""), page.text_content("#place-msg")
    page.wait_for_selector("#places td:has-text('ATRIUM')", timeout=WAIT_S * 1000)
    heading = page.text_content("#waypoints-file") or ""
    assert heading.endswith("/waypoints.yaml"), heading
    assert "/tmp" not in heading, heading  # short name
    assert "added ATRIUM to " + heading.removeprefix("— ") in (page.text_content("#place-msg") or "")
    text = (robot.tmp / "waypoints.yaml").read_text()
    assert "ATRIUM" in text
    assert "the atrium" in text
    page.screenshot(path=str(robot.artifacts / "admin.png"), full_page=True)
    page.close()
    teleop.wait_for_selector("#places button[data-place=ATRIUM]", timeout=WAIT_S * 1000)
    teleop.close()
    assert console.errors == []
