"""Visitors' push-to-talk (the seed's web_ptt.py), public and rate-limited per address.

- ``POST /api/talk/text`` ``{"text": "..."}`` → the brain's reply.
- ``POST /api/talk/audio`` (multipart field ``audio``: the browser's MediaRecorder WebM/Opus,
  or MP4/AAC from Safari) → ffmpeg → 16 kHz → speech to text → the brain →
  ``{"transcript", "reply"}``. ``tests/web/test_phone_e2e.py`` runs it end to end from Chromium's
  fake microphone over HTTPS with the real models.
- ``POST /api/talk/say`` ``{"text": "..."}`` → the reply spoken, as ``audio/wav``.
- ``GET /api/talk/robot_mic`` → ``{"available"}``; ``POST /api/talk/robot_mic`` ``{"text"}``:
  in the simulator only, the words are spoken into the simulated robot's microphone
  (``/sim/visitor_say``; the voice node synthesizes them), so the whole voice turn runs —
  wake word, listening, thinking, speaking — as for a visitor standing at the robot.
- Every typed or recorded turn is captioned on the kiosk face (the hub's ``captions``), and the
  face's phase is ``thinking`` from the upload to the reply (the hub's ``talk_turn``).
- ``GET /api/talk_url`` → ``{"url", "secure"}``: the address of ``/talk`` for a phone (HTTPS
  at the robot's network address when TLS is on); ``GET /api/talk_qr.svg``: it as a QR code
  (the kiosk face shows it).

The brain is reached through the ``converse`` action; voice through
``sage_robot.voice`` imported on first use. A missing part gives a 503 that names it
("voice is not installed", "the brain is not running").
"""

from __future__ import annotations

import asyncio
from typing import Any
from urllib.parse import urlsplit

from fastapi import APIRouter, HTTPException, Request, UploadFile
from fastapi.responses import Response

from sage_robot.brain.base import Utterance
from sage_robot.core import topics
from sage_robot.core.actions import GoalTimeout
from sage_robot.core.errors import SageError
from sage_robot.core.log import get_logger
from sage_robot.core.msgs import Text
from sage_robot.web import tls
from sage_robot.web.common import client_key, json_body, state_of

router = APIRouter()
MAX_QUESTION_CHARS = 500
MAX_SAY_CHARS = 2000
MAX_UPLOAD_BYTES = 5 * 1024 * 1024  # about 5 minutes of Opus speech
NOTHING_HEARD = "I did not hear any words; hold the button while you speak."
CONVERSE_TIMEOUT_S = 60.0  # longest a reply may take (LLM + tools), wall s

_log = get_logger("web")


def _limit(request: Request) -> None:
    st = state_of(request)
    key = client_key(request)
    if not st.talk_limiter.allow(key):
        wait = int(st.talk_limiter.retry_after_s(key)) + 1
        raise HTTPException(
            status_code=429,
            detail=f"too many questions; try again in {wait} s",
            headers={"Retry-After": str(wait)},
        )


def _voice(module: str) -> Any:
    import importlib

    try:
        return importlib.import_module(f"sage_robot.voice.{module}")
    except ImportError as exc:
        raise HTTPException(
            status_code=503, detail=f"voice is not installed ({exc.name or module} is missing)"
        ) from None


async def converse(request: Request, question: str) -> str:
    """Ask the brain; its whole reply. The question and the reply are captioned on the face."""
    st = state_of(request)
    bus = st.node.bus
    if not bus.actions.has(topics.CONVERSE):
        raise HTTPException(status_code=503, detail="the brain is not running")
    st.hub.caption("visitor", question, "talk")
    # Each visitor's device is a conversation of its own ("take me there" means their "there").
    turn = Utterance(question, f"web:{client_key(request)}")
    handle = await bus.actions.send_goal(topics.CONVERSE, turn)  # never waits
    try:  # the bound covers the wait behind other visitors' questions and the answer
        result = await handle.result(CONVERSE_TIMEOUT_S)
    except GoalTimeout:
        handle.request_cancel()
        raise HTTPException(status_code=504, detail="the brain took too long to answer") from None
    if not result.ok:
        raise HTTPException(status_code=502, detail=f"the brain could not answer: {result.message}")
    value = result.value
    reply = value.data if isinstance(value, Text) else str(value or "")
    st.hub.caption("robot", reply, "talk")
    return reply


def _question(text: Any) -> str:
    if not isinstance(text, str) or not text.strip():
        raise HTTPException(status_code=422, detail="text: type a question")
    if len(text) > MAX_QUESTION_CHARS:
        raise HTTPException(status_code=422, detail=f"text: at most {MAX_QUESTION_CHARS} characters")
    return " ".join(text.split())


@router.post("/api/talk/text")
async def talk_text(request: Request) -> dict[str, Any]:
    _limit(request)
    question = _question((await json_body(request)).get("text"))
    with state_of(request).hub.talk_turn():
        reply = await converse(request, question)
    _log.info("visitor question answered", client=client_key(request), chars=len(question))
    return {"transcript": question, "reply": reply}


@router.post("/api/talk/audio")
async def talk_audio(request: Request, audio: UploadFile) -> dict[str, Any]:
    _limit(request)
    data = await audio.read(MAX_UPLOAD_BYTES + 1)
    if len(data) > MAX_UPLOAD_BYTES:
        raise HTTPException(status_code=413, detail=f"recording too long (over {MAX_UPLOAD_BYTES} bytes)")
    audio_io, stt = _voice("audio_io"), _voice("stt")
    with state_of(request).hub.talk_turn():
        try:
            pcm = await asyncio.to_thread(audio_io.decode_upload, data, audio.filename or "recording")
            transcript = await asyncio.to_thread(stt.transcribe_pcm, pcm)
        except SageError as exc:
            raise HTTPException(status_code=422, detail=str(exc)) from None
        if transcript.empty:
            return {"transcript": "", "reply": "", "error": NOTHING_HEARD}
        reply = await converse(request, transcript.text)
    return {"transcript": transcript.text, "reply": reply}


def wake_phrase(request: Request) -> str:
    """The robot's first wake word as words ("hey jarvis"), from ``voice.wake_models``."""
    models = state_of(request).node.settings.voice.wake_models
    name = models[0].rsplit("/", 1)[-1].removesuffix(".onnx") if models else "hey_jarvis"
    return " ".join(name.replace("_", " ").split()) or "hey jarvis"


def robot_mic_available(request: Request) -> bool:
    """The simulated robot's microphone takes words: the simulator runs and its voice node
    listens on ``/sim/visitor_say`` (it subscribes only in simulation)."""
    node = state_of(request).node
    info = node.bus.topics().get(topics.SIM_VISITOR_SAY)
    return bool(node.clock.is_simulated and info is not None and getattr(info, "subscribers", None))


def robot_mic_words(wake: str, question: str) -> str:
    """What the simulated visitor says: the wake phrase as a sentence of its own, then the
    question ("Hey jarvis. Where is the cafe"); a wake phrase typed in front is not said twice.
    The simulated visitor says it in one go: the pipeline keeps words run on into the wake phrase."""
    if question.lower().startswith(wake):
        question = question[len(wake):].lstrip(" ,.!?;:")
    said = f"{wake[:1].upper()}{wake[1:]}."
    return f"{said} {question}" if question else said


@router.get("/api/talk/robot_mic")
async def robot_mic(request: Request) -> dict[str, Any]:
    return {"available": robot_mic_available(request), "wake": wake_phrase(request)}


@router.post("/api/talk/robot_mic")
async def say_to_robot(request: Request) -> dict[str, Any]:
    """Speak the words into the simulated robot's microphone (the answer comes from the robot:
    its face and speaker, not this reply)."""
    _limit(request)
    question = _question((await json_body(request)).get("text"))
    if not robot_mic_available(request):
        raise HTTPException(status_code=409, detail="only the simulated robot has a microphone to speak into")
    words = robot_mic_words(wake_phrase(request), question)
    state_of(request).node.bus.publish(topics.SIM_VISITOR_SAY, Text(words))
    _log.info("words spoken into the simulated microphone", client=client_key(request), chars=len(words))
    return {"ok": True, "spoken": words}


@router.post("/api/talk/say")
async def talk_say(request: Request) -> Response:
    _limit(request)
    text = (await json_body(request)).get("text")
    if not isinstance(text, str) or not text.strip() or len(text) > MAX_SAY_CHARS:
        raise HTTPException(status_code=422, detail=f"text: 1..{MAX_SAY_CHARS} characters to speak")
    tts, audio_io = _voice("tts"), _voice("audio_io")
    try:
        pcm, rate = await asyncio.to_thread(tts.synthesize, text)
    except (SageError, ImportError, OSError) as exc:
        raise HTTPException(status_code=503, detail=f"text to speech failed: {exc}") from None
    return Response(audio_io.wav_bytes(pcm, rate), media_type="audio/wav")


def talk_url(request: Request) -> str:
    """``/talk`` as a phone on the robot's network reaches it: ``web.public_host``, else the
    address this request came to when that is not loopback, else the robot's first LAN address."""
    node = state_of(request).node
    web = node.settings.web
    host = web.public_host
    if not host:
        asked = urlsplit(f"//{request.headers.get('host', '')}").hostname or ""
        host = asked if asked and not tls.is_loopback(asked) else tls.public_host(web)
    secure = bool(getattr(node, "tls", False))
    port = int(getattr(node, "port", web.port))
    scheme, default = ("https", 443) if secure else ("http", 80)
    return f"{scheme}://{tls.url_host(host)}{'' if port == default else f':{port}'}/talk"


def qr_svg(text: str) -> str:
    """``text`` as an SVG QR code (black on white, quiet zone included)."""
    import io

    import segno

    out = io.BytesIO()
    segno.make(text, error="m", micro=False).save(
        out, kind="svg", scale=8, border=4, dark="#000", light="#fff", xmldecl=False,
        title="QR code: " + text,
    )
    return out.getvalue().decode()


@router.get("/api/talk_url")
async def talk_address(request: Request) -> dict[str, Any]:
    url = talk_url(request)
    return {"url": url, "secure": url.startswith("https://")}


@router.get("/api/talk_qr.svg")
async def talk_qr(request: Request) -> Response:
    url = talk_url(request)
    return Response(qr_svg(url), media_type="image/svg+xml",
                    headers={"Cache-Control": "no-cache", "X-Talk-URL": url})
