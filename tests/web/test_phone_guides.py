"""Issue #21's phone test as written: a phone-sized Chromium on the robot's **non-loopback**
address over HTTPS, its (fake) microphone saying "take me to the cafe": hold to talk → the
transcript and the reply on the phone, the robot starts guiding, and the kiosk face thinks
while the question is answered, then shows the caption and the guiding card.

The robot is the simulator (real navigator, real offline brain, web on HTTPS listening on every
address); speech to text is the real bundled Whisper; the microphone is Chromium's fake capture
device playing a WAV made with the robot's own Piper voice.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from ..support.waits import wait_until
from .conftest import SimRobot, sim_robot
from .test_https import lan_ip
from .test_phone_e2e import (
    ANSWER_WAIT_MS,
    FACE_PHASES,
    FAILED,
    PAGE_PROBE,
    PHONE,
    QUIET_AFTER_SPEECH_MS,
    WAIT_MS,
    fake_mic_chromium,
    spoken_wav,
)

pytest.importorskip("faster_whisper", reason="the phone test needs: pip install 'sage-robot[voice]'")
pytestmark = pytest.mark.browser

REQUEST = "Take me to the cafe."  # the words
KIOSK = {"width": 1280, "height": 800}
DRIVE_WAIT_S = 60.0  # the robot is moving this long after the reply at the latest (wall s)
MOVING_MPS = 0.05  # odometry faster than this: the robot drives


@pytest.fixture(scope="module")
def request_wav(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return spoken_wav(tmp_path_factory.mktemp("mic"), REQUEST)


@pytest.fixture(scope="module")
def robot(tmp_path_factory: pytest.TempPathFactory) -> Iterator[SimRobot]:
    lan_ip()
    with sim_robot(tmp_path_factory, "guide", web={"tls": "on", "http_port": None, "host": "0.0.0.0"}) as sim:
        yield sim


@pytest.fixture(scope="module")
def chromium(request_wav: Path) -> Iterator[Any]:
    with fake_mic_chromium(request_wav) as b:
        yield b


def test_phone_on_the_lan_address_asks_to_be_taken_and_the_robot_guides(
    chromium: Any, robot: SimRobot
) -> None:
    if "converse" in robot.stand_ins or "navigate_to" in robot.stand_ins:
        pytest.skip(f"needs the real brain and navigator (stand-ins here: {robot.stand_ins})")
    port = robot.url.rsplit(":", 1)[1]
    base = f"https://{lan_ip()}:{port}"
    kiosk_ctx = chromium.new_context(viewport=KIOSK, ignore_https_errors=True)
    phone_ctx = chromium.new_context(viewport=PHONE, ignore_https_errors=True, has_touch=True,
                                     is_mobile=True, permissions=["microphone"])
    phone_ctx.add_init_script(PAGE_PROBE)
    kiosk_ctx.add_init_script(FACE_PHASES)
    try:
        face = kiosk_ctx.new_page()
        face.goto(f"{robot.url}/face")
        face.wait_for_selector("#link.up", timeout=WAIT_MS)  # it hears the robot before the question
        phone = phone_ctx.new_page()
        phone.goto(f"{base}/talk")
        assert phone.evaluate("window.isSecureContext") is True, "https at the LAN address"
        phone.wait_for_function("document.body.dataset.mic === 'available'", timeout=WAIT_MS)
        box = phone.locator("#ptt").bounding_box()
        assert box is not None
        phone.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
        phone.mouse.down()  # hold to talk while the microphone says the request
        phone.wait_for_selector("#ptt.recording", timeout=WAIT_MS)
        phone.wait_for_function(
            f"window.micProbe.loudBlocks > 5 && window.micProbe.quietMs > {QUIET_AFTER_SPEECH_MS}",
            timeout=WAIT_MS)
        phone.mouse.up()
        phone.wait_for_function(f"Number(document.body.dataset.replies || 0) >= 1 || {FAILED}",
                                timeout=ANSWER_WAIT_MS)
        status = phone.text_content("#status") or ""
        assert phone.get_attribute("body", "data-talk") == "idle", f"the phone says: {status}"
        heard = phone.text_content(".bubble.you") or ""
        reply = phone.text_content(".bubble.sage") or ""
        phone.screenshot(path=str(robot.artifacts / "talk-phone-lan-guide.png"))
        assert re.search(r"\btake me\b.*\bcaf[eé]\b", heard, re.IGNORECASE), f"whisper heard {heard!r}"
        assert reply.strip(), "the phone shows the robot's reply"
        face.wait_for_function(  # the kiosk face captions the turn
            "(text) => document.body.innerText.includes(text)", arg=reply.strip()[:40], timeout=WAIT_MS)
        phases = face.evaluate("window.phaseLog")
        assert "thinking" in phases, f"the face thinks while the phone's question is answered: {phases}"

        def driving() -> bool:
            odom = robot.odom
            return odom is not None and abs(odom.twist.linear_x) > MOVING_MPS

        wait_until(driving, "the robot to start guiding (moving)", DRIVE_WAIT_S)
        face.wait_for_selector("#guide:not([hidden])", timeout=WAIT_MS)
        title = face.text_content("#guide-title") or ""
        assert re.search(r"caf[eé]", title, re.IGNORECASE), f"the guiding card says {title!r}"
        assert face.is_visible("#guide-stop"), "the guiding card has a Stop"
        face.screenshot(path=str(robot.artifacts / "face-guiding-after-phone.png"))
    finally:
        phone_ctx.close()
        kiosk_ctx.close()
