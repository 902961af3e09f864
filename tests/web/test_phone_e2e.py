"""A visitor's phone end to end (issue #21): real Chromium at phone size records a question from
its (fake) microphone, uploads the WebM/Opus to the robot over HTTPS, and the robot's real
ffmpeg → faster-whisper (bundled tiny.en) → brain path answers; the page shows "thinking…",
then the transcript and the reply, or a clear error.

The microphone is Chromium's fake capture device playing a WAV that the test makes with the
robot's own Piper voice (``--use-file-for-fake-audio-capture``, 16-bit PCM, played once). The
robot is the simulator with the web node on HTTPS (``web.tls: on``) at loopback.
"""

from __future__ import annotations

import contextlib
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from sage_robot.app.registry import NODES
from sage_robot.web.node import WebNode

from ..support.waits import wait_until
from .conftest import CHROMIUM, CHROMIUM_ARGS, SimRobot, sim_robot

pytest.importorskip("faster_whisper", reason="the phone test needs: pip install 'sage-robot[voice]'")
pytestmark = pytest.mark.browser

QUESTION = "Where are the bathrooms?"
# Whisper tiny.en on a phone's compressed recording (AAC on Safari) may mishear a word ("cafe"
# came back once as "capping"): the transcript must say where + bathroom(s), words it keeps.
HEARD = r"\bwhere\b.*\bbath ?rooms?\b"
WAV_RATE_HZ = 48_000  # Chromium's capture rate; the WAV is 16-bit PCM mono at it
LEAD_SILENCE_S = 0.6  # before the words: the recorder starts just after the device opens
TAIL_SILENCE_S = 4.0  # after them (the file plays once, then the device gives silence)
WAIT_MS = 30_000
ANSWER_WAIT_MS = 180_000  # ffmpeg, speech to text and the brain on a busy machine
VOICE_WAIT_S = 240.0  # the voice node loads its models, then hears, transcribes and answers
QUIET_AFTER_SPEECH_MS = 700  # the button is released once the words are over for this long
LOUD_RMS = 0.02  # a 20 ms block of the microphone louder than this holds speech
PHONE = {"width": 390, "height": 844}
FAILED = "document.body.dataset.talk === 'error'"  # the page shows a failure
REFUSAL_TRIES = 5  # the page asks, at most, this often until the rate limit refuses it
MAX_SPENT = 100  # questions the rate limit must refuse before (its burst is a few)

# Installed before the page's scripts: every #status text in order (to see "thinking…" between
# the question and the reply, however short), and a level meter on each microphone stream the
# page opens (so the test releases the button when the words are over, not after a fixed time).
PAGE_PROBE = """
(() => {
  window.statusLog = [];
  document.addEventListener("DOMContentLoaded", () => {
    const status = document.getElementById("status");
    new MutationObserver(() => window.statusLog.push(status.textContent)).observe(
      status, { childList: true, characterData: true, subtree: true });
  });
  window.micProbe = { loudBlocks: 0, quietMs: 0, mimeTypes: [] };
  const Recorder = window.MediaRecorder;
  if (Recorder) {
    window.MediaRecorder = class extends Recorder {
      start(...args) {
        window.micProbe.mimeTypes.push(this.mimeType);
        return super.start(...args);
      }
    };
  }
  const devices = navigator.mediaDevices;
  if (!devices) return;
  const open = devices.getUserMedia.bind(devices);
  devices.getUserMedia = async (constraints) => {
    const stream = await open(constraints);
    const ac = new AudioContext();
    const meter = ac.createAnalyser();
    meter.fftSize = 1024;
    ac.createMediaStreamSource(stream).connect(meter);
    const block = new Float32Array(meter.fftSize);
    let lastLoud = null;
    const tick = () => {
      meter.getFloatTimeDomainData(block);
      const rms = Math.sqrt(block.reduce((s, x) => s + x * x, 0) / block.length);
      const now = performance.now();
      if (rms > LOUD_RMS) { window.micProbe.loudBlocks += 1; lastLoud = now; }
      window.micProbe.quietMs = lastLoud === null ? 0 : now - lastLoud;
      if (stream.active) setTimeout(tick, 20); else ac.close();
    };
    tick();
    return stream;
  };
})();
""".replace("LOUD_RMS", repr(LOUD_RMS))


def spoken_wav(folder: Path, text: str) -> Path:
    """``text`` in the robot's Piper voice, padded with silence, as Chromium's microphone wants it.
    Deterministic (no prosody noise): the same audio every run. With Piper's own noise, one CI
    run in several heard "Take me to the cap-aid." and failed."""
    from sage_robot.core.errors import ConfigError
    from sage_robot.voice.audio_io import resample, to_int16, write_wav
    from sage_robot.voice.tts import PiperEngine, Speech

    try:
        speech = Speech(PiperEngine(deterministic=True))
    except ConfigError:
        pytest.skip("the Piper voice is not installed: pip install 'sage-robot[voice-gpl]'")
    words = resample(to_int16(speech.synthesize(text)), speech.sample_rate, WAV_RATE_HZ)
    pad = [np.zeros(round(s * WAV_RATE_HZ), np.int16) for s in (LEAD_SILENCE_S, TAIL_SILENCE_S)]
    return write_wav(folder / "speech.wav", np.concatenate([pad[0], words, pad[1]]), WAV_RATE_HZ)


@contextlib.contextmanager
def fake_mic_chromium(wav: Path) -> Iterator[Any]:
    """Chromium whose microphone says ``wav`` once each time a page opens it."""
    if not Path(CHROMIUM).exists():
        pytest.fail(f"{CHROMIUM} is missing: apt-get install chromium (see scripts/apt-packages.txt)")
    from playwright.sync_api import sync_playwright

    args = [*CHROMIUM_ARGS, f"--use-file-for-fake-audio-capture={wav}%noloop"]
    with sync_playwright() as pw:
        b = pw.chromium.launch(executable_path=CHROMIUM, args=args, headless=True)
        try:
            yield b
        finally:
            with contextlib.suppress(Exception):
                b.close()


@pytest.fixture(scope="module")
def question_wav(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return spoken_wav(tmp_path_factory.mktemp("mic"), QUESTION)


@pytest.fixture(scope="module")
def robot(tmp_path_factory: pytest.TempPathFactory) -> Iterator[SimRobot]:
    web = {"tls": "on", "http_port": None}
    voice = ("voice",) if "voice" in NODES else ()  # the simulated robot's own microphone
    with sim_robot(tmp_path_factory, "phone", web=web, extra_nodes=voice) as sim:
        yield sim


@pytest.fixture(scope="module")
def phone_browser(question_wav: Path) -> Iterator[Any]:
    with fake_mic_chromium(question_wav) as b:
        yield b


@pytest.fixture
def phone(phone_browser: Any) -> Iterator[Any]:
    ctx = phone_browser.new_context(viewport=PHONE, ignore_https_errors=True, has_touch=True,
                                    is_mobile=True, permissions=["microphone"])
    ctx.add_init_script(PAGE_PROBE)
    try:
        yield ctx
    finally:
        ctx.close()


def open_talk(ctx: Any, robot: SimRobot) -> Any:
    assert robot.url.startswith("https://"), robot.url
    page = ctx.new_page()
    page.goto(f"{robot.url}/talk")
    assert page.evaluate("window.isSecureContext") is True
    return page


def robot_captions(robot: SimRobot) -> list[str]:
    node: WebNode = robot.web_node()
    return [c["text"] for c in list(node.hub.captions) if c["who"] == "robot"]


def thought_then(page: Any, final: str) -> list[str]:
    """The #status texts in order; asserts "thinking…" was shown and then ``final`` replaced it
    (a status after that, the reply's voice, is not this check's)."""
    log: list[str] = page.evaluate("window.statusLog")
    assert "thinking…" in log, log
    after = log.index("thinking…") + 1
    assert after < len(log), log
    assert log[after] == final, log
    return log


# Safari (every iPhone browser) records MP4/AAC only: what its MediaRecorder says it supports.
SAFARI_RECORDER = """
window.MediaRecorder.isTypeSupported = (type) => type.startsWith("audio/mp4");
"""


@pytest.mark.parametrize(("browser_like", "recorded"), [("chrome", "audio/webm"), ("safari", "audio/mp4")])
def test_phone_speaks_a_question_and_sees_transcript_and_reply(phone: Any, robot: SimRobot, browser_like: str,
                                                               recorded: str) -> None:
    if browser_like == "safari":
        phone.add_init_script(SAFARI_RECORDER)
    page = open_talk(phone, robot)
    uploads: list[str] = []  # each upload's content type

    def on_request(request: Any) -> None:
        if "/api/talk/audio" in request.url:
            uploads.append(request.headers.get("content-type", ""))

    page.on("request", on_request)
    page.wait_for_function("document.body.dataset.mic === 'available'", timeout=WAIT_MS)
    box = page.locator("#ptt").bounding_box()
    assert box is not None
    page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
    page.mouse.down()  # hold to talk while the microphone says the question
    page.wait_for_selector("#ptt.recording", timeout=WAIT_MS)
    words_over = f"window.micProbe.loudBlocks > 5 && window.micProbe.quietMs > {QUIET_AFTER_SPEECH_MS}"
    page.wait_for_function(words_over, timeout=WAIT_MS)
    page.mouse.up()
    answered = f"Number(document.body.dataset.replies || 0) >= 1 || {FAILED}"
    page.wait_for_function(answered, timeout=ANSWER_WAIT_MS)
    status = page.text_content("#status") or ""
    assert page.get_attribute("body", "data-talk") == "idle", f"the page says: {status}"
    heard = page.text_content(".bubble.you") or ""
    reply = page.text_content(".bubble.sage") or ""
    page.screenshot(path=str(robot.artifacts / f"talk-phone-e2e-{browser_like}.png"))
    assert re.search(HEARD, heard, re.IGNORECASE), f"whisper heard {heard!r}"
    assert uploads, "the page uploads the recording"
    assert uploads[0].startswith("multipart/form-data"), uploads
    mimes = page.evaluate("window.micProbe.mimeTypes")
    assert mimes, "MediaRecorder recorded"
    assert mimes[0].startswith(recorded), f"MediaRecorder records {recorded} here, not {mimes}"
    assert reply.strip(), "the page shows the brain's reply"
    assert reply == robot_captions(robot)[-1], "the reply shown is the one the brain gave (captioned)"
    if "converse" in robot.stand_ins:
        assert heard in robot.questions
    thought_then(page, "")


def test_typed_question_shows_thinking_then_the_reply(phone: Any, robot: SimRobot) -> None:
    page = open_talk(phone, robot)
    page.fill("#question", "What is your name?")
    page.click("#ask-btn")
    page.wait_for_selector(".bubble.sage", timeout=ANSWER_WAIT_MS)
    thought_then(page, "")
    assert page.get_attribute("body", "data-talk") == "idle"
    assert page.text_content(".bubble.sage") == robot_captions(robot)[-1]


def test_failed_question_says_why_in_one_clear_line(phone: Any, robot: SimRobot) -> None:
    page = open_talk(phone, robot)
    page.route("**/api/talk/text", lambda route: route.abort("internetdisconnected"))  # the Wi-Fi drops
    page.fill("#question", "Where is the library?")
    page.click("#ask-btn")
    page.wait_for_function("document.body.dataset.talk === 'error'", timeout=WAIT_MS)
    status = page.locator("#status")
    assert "could not be reached" in (status.text_content() or "")
    assert "error" in (status.get_attribute("class") or "")
    thought_then(page, status.text_content() or "")
    assert page.locator(".bubble").count() == 0
    assert page.is_enabled("#ask-btn"), "the visitor can ask again"
    page.unroute("**/api/talk/text")


def captions(robot: SimRobot) -> list[dict[str, Any]]:
    return list(robot.web_node().hub.captions)


# Installed before the face's scripts: every phase the face shows, in order.
FACE_PHASES = """
window.phaseLog = [];
document.addEventListener("DOMContentLoaded", () => {
  new MutationObserver(() => {
    const phase = document.body.dataset.phase;
    if (window.phaseLog[window.phaseLog.length - 1] !== phase) window.phaseLog.push(phase);
  }).observe(document.body, { attributes: true, attributeFilter: ["data-phase"] });
});
"""
VOICE_TURN = ["listening", "thinking", "speaking"]  # what the face shows of a turn, in order


def in_order(wanted: list[str], seen: list[str]) -> bool:
    """``wanted`` is a subsequence of ``seen``."""
    it = iter(seen)
    return all(any(s == w for s in it) for w in wanted)


def test_robot_mic_runs_a_whole_voice_turn_in_the_simulator(phone: Any, phone_browser: Any,
                                                            robot: SimRobot) -> None:
    """The typed words, with "Say it to the robot" on, go into the simulated robot's microphone:
    the voice node hears the wake word, transcribes the question (/sage/heard) and speaks the
    brain's reply; the kiosk face goes through listening, thinking and speaking and captions
    the question and the answer."""
    if "voice" not in robot.node_names:
        pytest.skip("the voice node is not registered here")
    import httpx

    def mic_open() -> bool:
        resp = httpx.get(f"{robot.url}/api/talk/robot_mic", verify=False, timeout=30)
        return bool(resp.json()["available"])

    wait_until(mic_open, "the voice node to listen on the simulated microphone", VOICE_WAIT_S)
    kiosk = phone_browser.new_context(viewport={"width": 1280, "height": 800}, ignore_https_errors=True)
    kiosk.add_init_script(FACE_PHASES)
    face = kiosk.new_page()
    try:
        face.goto(f"{robot.url}/face")
        face.wait_for_selector("#link.up", timeout=WAIT_MS)
        page = open_talk(phone, robot)
        page.wait_for_selector("#robot-mic", state="visible", timeout=WAIT_MS)
        page.check("#robot-mic-on")
        seen = max((c["id"] for c in captions(robot)), default=0)  # the face keeps only the last few
        page.fill("#question", QUESTION)
        page.click("#ask-btn")
        page.wait_for_function("Number(document.body.dataset.saidToRobot || 0) >= 1", timeout=WAIT_MS)
        assert "said to the robot" in (page.text_content("#status") or "")
        assert page.locator(".bubble").count() == 0, "the answer comes from the robot, not the page"

        def turn() -> list[dict[str, Any]] | None:
            new = [c for c in captions(robot) if c["id"] > seen]
            heard = [c for c in new if c["via"] == "microphone"]
            spoken = [c for c in new if c["via"] == "voice"]
            return new if heard and spoken else None

        new = wait_until(turn, "the robot to hear the question and speak its answer", VOICE_WAIT_S)
        heard = next(c["text"] for c in new if c["via"] == "microphone")
        assert re.search(HEARD, heard, re.IGNORECASE), f"the robot's microphone heard {heard!r}"
        answer = next(c["text"] for c in new if c["via"] == "voice")
        assert answer.strip()
        face.wait_for_function(f"(({VOICE_TURN!r}).every((p) => window.phaseLog.includes(p)))",
                               timeout=WAIT_MS)
        phases = face.evaluate("window.phaseLog")
        assert in_order(VOICE_TURN, phases), f"the face showed {phases}"
        # the answer is under the face: live (#reply) while its turn shows, then a caption line
        face.wait_for_function("(text) => document.querySelector('.captions').textContent.includes(text)",
                               arg=answer[:40], timeout=WAIT_MS)
        face.screenshot(path=str(robot.artifacts / "face-robot-mic-turn.png"))
    finally:
        kiosk.close()


def use_up_questions(robot: SimRobot) -> int:
    """Spend this address's questions (``web.talk_per_min``, a burst of a few) with empty ones,
    which the robot counts before it refuses them (422); the number spent."""
    import httpx

    with httpx.Client(base_url=robot.url, verify=False, timeout=30, headers={"Origin": robot.url}) as c:
        for spent in range(MAX_SPENT):
            resp = c.post("/api/talk/text", json={"text": ""})
            if resp.status_code == 429:
                return spent
            assert resp.status_code == 422, resp.text
    raise AssertionError(f"the rate limit allowed {MAX_SPENT} questions in a row")


def test_robot_refusal_is_said_with_its_reason(phone: Any, robot: SimRobot) -> None:
    """The robot's own refusal (here its rate limit on questions from one address) reaches the
    visitor as one line with the reason, and the page stays usable."""
    page = open_talk(phone, robot)
    for i in range(REFUSAL_TRIES):  # a question may slip in when the limit refills meanwhile
        use_up_questions(robot)
        answered = page.locator(".bubble.sage").count()
        page.fill("#question", f"Question number {i + 1}?")
        page.click("#ask-btn")
        page.wait_for_function(
            f"document.querySelectorAll('.bubble.sage').length > {answered} || {FAILED}",
            timeout=ANSWER_WAIT_MS)
        if page.get_attribute("body", "data-talk") == "error":
            break
    status = page.text_content("#status") or ""
    assert page.get_attribute("body", "data-talk") == "error", "the rate limit never refused"
    assert re.fullmatch(r"Sorry, no answer: too many questions; try again in \d+ s", status), status
    assert page.is_enabled("#ask-btn")
