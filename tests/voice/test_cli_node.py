"""`sage voice ...` commands (in-process, real models) and the VoiceNode in simulation."""

from __future__ import annotations

import asyncio
import json

import pytest

from sage_robot.cli.main import main
from sage_robot.core.bus import Bus
from sage_robot.core.clock import SimClock
from sage_robot.core.config import Settings
from sage_robot.core.msgs import Text
from sage_robot.core.msgs.voice import AudioChunk, Phase, UiState
from sage_robot.core.node import NodeContext
from sage_robot.core.resources import Resources
from sage_robot.core.topics import HEARD, SIM_VISITOR_AUDIO, SIM_VISITOR_SAY, UI_STATE
from sage_robot.voice import node as voice_node
from sage_robot.voice.audio_io import load_audio
from sage_robot.voice.node import SIM_AUDIO_KEY, SIM_OUT_DIR_KEY, VoiceNode

from ..support.waits import until

WAIT_S = 90.0


def test_transcribe_json(pocketsphinx_data, capsys):
    assert main(["voice", "transcribe", str(pocketsphinx_data / "goforward.raw"), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["text"].lower().startswith("go forward")
    assert out["segments"]


def test_say_to_wav_then_wake_json(tmp_path, capsys):
    wav = tmp_path / "hey.wav"
    assert main(["voice", "say", "Hey Jarvis. The lab is 2 km away.", "--out", str(wav)]) == 0
    assert "wrote" in capsys.readouterr().out
    assert len(load_audio(wav)) > 16000
    assert main(["voice", "wake", str(wav), "--model", "hey_jarvis", "--model", "alexa", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert [d["model"] for d in out["detections"]] == ["hey_jarvis"]
    assert out["detections"][0]["time_s"] < 2.0
    assert out["max_scores"]["alexa"] < 0.1


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["voice", "transcribe", "/nonexistent.wav"], "no such audio file"),
        (["voice", "wake", "/nonexistent.wav", "--threshold", "2"], "between 0 and 1"),
        (["voice", "say", "  "], "nothing to say"),
    ],
)
def test_bad_input_is_one_clear_line(argv, message, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err
    assert "Traceback" not in err
    assert len(err.strip().splitlines()) == 1


async def test_voice_node_in_simulation(models, monkeypatch, tmp_path, pocketsphinx_data):
    """The node wires the sim mic/speaker: a simulated visitor says the wake word (text
    rendered into the mic) and a recorded command (audio into the mic); the robot hears it,
    has no brain to ask, says so, and writes what it said as a WAV file."""
    monkeypatch.setattr(voice_node.VoiceModels, "load", classmethod(lambda cls, s: models))
    clock = SimClock()
    bus = Bus(clock)
    ctx = NodeContext(bus, clock, Settings(), Resources({SIM_OUT_DIR_KEY: tmp_path}))
    heard: list[str] = []
    ui: list[UiState] = []
    bus.subscribe(HEARD, Text, lambda m: heard.append(m.data))
    bus.subscribe(UI_STATE, UiState, ui.append, maxsize=10000)
    node = VoiceNode(ctx)
    await node.setup()

    async def lockstep(dt: float) -> None:
        audio = ctx.resources.get(SIM_AUDIO_KEY)
        if audio is not None:
            await audio[0].lockstep()

    stop = asyncio.Event()
    runner = asyncio.create_task(clock.run(0.02, speed=None, stop=stop, on_step=lockstep))
    try:
        await until(lambda: node.pipeline is not None, timeout=WAIT_S)
        await until(lambda: bus.topics().get(SIM_VISITOR_SAY) is not None, timeout=WAIT_S)
        bus.publish(SIM_VISITOR_SAY, Text("Hey Jarvis."))
        await until(lambda: node.pipeline is not None and node.pipeline.detections, timeout=WAIT_S)
        go = load_audio(pocketsphinx_data / "goforward.raw")  # a real recording, as a WAV would be
        bus.publish(SIM_VISITOR_AUDIO, AudioChunk(clock.now(), 16000, go.astype("<i2").tobytes()))
        await until(lambda: list(tmp_path.glob("*.wav")), timeout=WAIT_S)
    finally:
        stop.set()
        runner.cancel()
        await asyncio.gather(runner, return_exceptions=True)
        await node._close()
        await node.teardown()
    assert heard
    assert heard[0].lower().startswith("go forward")
    assert any(u.error_msg == "brain not running" for u in ui)
    assert Phase.SPEAKING in {u.phase for u in ui}
    assert node.stats()["turns"] == 1


def test_listen_without_a_microphone_is_one_clear_line(capsys):
    sd = pytest.importorskip("sounddevice")
    try:
        has_input = any(d["max_input_channels"] > 0 for d in sd.query_devices())
    except Exception:
        has_input = False
    if has_input:
        pytest.skip("this machine has a microphone; the error path needs none")
    assert main(["voice", "listen", "--seconds", "1"]) == 2
    err = capsys.readouterr().err
    assert "microphone" in err
    assert "Traceback" not in err
    assert len(err.strip().splitlines()) == 1
