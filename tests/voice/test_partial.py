"""Partial transcripts (``asr_partial``) while the visitor speaks: real Whisper (a second
tiny.en instance), on the wall clock (the partial runs in a worker thread at the speed
of the CPU, so the microphone must run in real time for the order to mean anything)."""

from __future__ import annotations

import asyncio

import numpy as np
import pytest

from sage_robot.core.bus import Bus
from sage_robot.core.clock import WallClock
from sage_robot.core.msgs import Text
from sage_robot.core.msgs.voice import UiState
from sage_robot.core.topics import CONVERSE, UI_STATE
from sage_robot.sim.audio import SimMicrophone, SimSpeaker
from sage_robot.voice.node import build_pipeline
from sage_robot.voice.pipeline import State

from ..support.waits import until
from .conftest import silence

WAIT_S = 60.0  # bound on the turn (real seconds; the audio itself is ~10 s)
LONG = ("The robotics lab on the first floor has three big robot arms, and the students "
        "built a small rover that drives around the campus every Friday afternoon.")  # fmt: skip


async def test_partial_transcript_arrives_before_the_final(voice_settings, models, say16k):
    """The partial process at normal priority here: at nice +10 on a machine loaded by
    other work a partial may (by design) come too late to show, which would say nothing
    about the pipeline's ordering."""
    from sage_robot.voice.partial import PartialTranscriber

    clock = WallClock()
    bus = Bus(clock)
    ui: list[UiState] = []
    bus.subscribe(UI_STATE, UiState, ui.append, maxsize=10000)

    async def echo(goal: Text, ctx) -> Text:
        return Text("Okay.")

    bus.actions.serve(CONVERSE, echo)
    mic = SimMicrophone(clock)
    pipe = build_pipeline(bus, clock, voice_settings, models, mic, SimSpeaker(clock, mic, echo_gain=0.1))
    assert pipe.partial_stt is models.stt_partial
    assert pipe.partial_stt is not None
    pipe.partial_stt = PartialTranscriber(nice=0)
    speech = say16k(LONG)
    assert len(speech) / 16000 > 5.0
    mic.inject(np.concatenate([silence(0.5), say16k("Hey Jarvis."), silence(0.5), speech,
                               silence(1.0)]))  # fmt: skip
    task = asyncio.create_task(pipe.run())
    try:
        await until(lambda: pipe.latencies and pipe.state is State.IDLE and not pipe.mouth.speaking,
                    "the turn to end", timeout=WAIT_S, poll=0.05)
    finally:
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
        pipe.partial_stt.close()
    final = next(i for i, u in enumerate(ui) if u.asr_final)
    partials = [u.asr_partial for u in ui[:final] if u.asr_partial]
    assert partials, f"no partial before the final; stats={pipe.stats()}"
    assert "robot" in " ".join(partials).lower()  # the start of the utterance, transcribed
    assert "friday" in ui[final].asr_final.lower()
    assert len(partials[0]) < len(ui[final].asr_final)  # a partial is the utterance so far
    assert pipe.partials == len(set(partials))
    assert pipe.latencies[0].reply_delay_s > 0


def test_partials_can_be_switched_off(voice_settings, models):
    clock = WallClock()
    bus = Bus(clock)
    mic = SimMicrophone(clock)
    off = voice_settings.model_copy(update={"asr_partial": False})
    pipe = build_pipeline(bus, clock, off, models, mic, SimSpeaker(clock, mic, echo_gain=0.1))
    assert pipe.partial_stt is None
    pipe.recorder.push(np.zeros(1280, np.int16), 1.0)
    pipe.live.transcribe_partial(pipe.recorder)  # no model: nothing starts
    assert pipe.live.partial_task is None


@pytest.mark.parametrize("interval_s", [0.0, -1.0])
def test_partial_interval_must_be_positive(interval_s):
    from pydantic import ValidationError

    from sage_robot.core.config.areas import VoiceSettings

    with pytest.raises(ValidationError, match="asr_partial_interval_s"):
        VoiceSettings(asr_partial_interval_s=interval_s)


def test_partial_process_runs_at_lower_priority(models, pocketsphinx_data):
    import os

    from sage_robot.voice.audio_io import load_audio
    from sage_robot.voice.partial import PARTIAL_NICE

    part = models.stt_partial
    assert part is not None
    assert part.pid != os.getpid()
    mine = os.getpriority(os.PRIO_PROCESS, 0)
    assert os.getpriority(os.PRIO_PROCESS, part.pid) == min(19, mine + PARTIAL_NICE)
    text = part.transcribe(load_audio(pocketsphinx_data / "goforward.raw")).text.lower()
    assert "forward" in text


def test_partial_model_errors_are_clear():
    from sage_robot.core.errors import ConfigError
    from sage_robot.voice.partial import PartialTranscriber

    with pytest.raises(ConfigError, match="STT model 'no-such-model'"):
        PartialTranscriber("no-such-model")
