"""The pipeline state machine through whole turns: real models, a real Bus, a fake brain
that serves the ``converse`` action, the simulated room (mic + speaker with echo) on a
SimClock held in lockstep with the microphone's reader (simulated time runs as fast as
the models keep up, and never ahead of them)."""

from __future__ import annotations

import asyncio
import math
from collections.abc import Sequence

import numpy as np
import pytest

from sage_robot.core.bus import Bus
from sage_robot.core.clock import SimClock
from sage_robot.core.msgs import Text
from sage_robot.core.msgs.nav import NavigateFeedback, NavState
from sage_robot.core.msgs.voice import AudioChunk, Phase, TurnLatency, UiState
from sage_robot.core.topics import (
    AUDIO_OUT,
    CONVERSE,
    HEARD,
    NAV_STATE,
    SAY,
    TURN_LATENCY,
    UI_STATE,
)
from sage_robot.sim.audio import ECHO_GAIN, NOISE_FLOOR_RMS, SimMicrophone, SimSpeaker
from sage_robot.voice.node import build_pipeline
from sage_robot.voice.pipeline import State
from sage_robot.voice.turn import NO_BRAIN

from ..support.waits import until as support_until
from .conftest import silence

WAIT_S = 90.0  # bound on every wait (real seconds)


class Room:
    """A bus, a SimClock driven in the background, the sim mic/speaker and a pipeline."""

    def __init__(self, settings, models, echo_gain: float = ECHO_GAIN,
                 noise_rms: float = NOISE_FLOOR_RMS) -> None:  # fmt: skip
        self.clock = SimClock()
        self.bus = Bus(self.clock)
        self.mic = SimMicrophone(self.clock, noise_rms=noise_rms)
        self.speaker = SimSpeaker(self.clock, self.mic, echo_gain=echo_gain)
        self.pipeline = build_pipeline(self.bus, self.clock, settings, models, self.mic, self.speaker)
        self.ui: list[UiState] = []
        self.heard: list[str] = []
        self.latency: list[TurnLatency] = []
        self.audio: list[AudioChunk] = []
        self.bus.subscribe(UI_STATE, UiState, self.ui.append, maxsize=10000)
        self.bus.subscribe(HEARD, Text, lambda m: self.heard.append(m.data), maxsize=100)
        self.bus.subscribe(TURN_LATENCY, TurnLatency, self.latency.append, maxsize=100)
        self.bus.subscribe(AUDIO_OUT, AudioChunk, self.audio.append, maxsize=100000)
        self._stop = asyncio.Event()

    async def __aenter__(self) -> Room:
        self._tasks = [
            asyncio.create_task(self.pipeline.run()),
            asyncio.create_task(
                self.clock.run(0.02, speed=None, stop=self._stop, on_step=self.mic.lockstep)
            ),
        ]
        await self.until(lambda: self.bus.topics().get(SAY) is not None, "the pipeline to start")
        return self

    async def __aexit__(self, *exc) -> None:
        self._stop.set()
        for t in self._tasks:
            t.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)

    async def until(self, cond, what: str) -> None:
        await support_until(cond, what, timeout=WAIT_S, poll=0.02,
                            detail=lambda: f"state={self.pipeline.stats()}")

    def phases(self) -> list[Phase]:
        out: list[Phase] = []
        for u in self.ui:
            if not out or out[-1] is not u.phase:
                out.append(u.phase)
        return out

    def idle(self) -> bool:
        p = self.pipeline
        return p.state is State.IDLE and not p.mouth.speaking and self.mic.pending_s == 0


def echo_brain(bus: Bus, clock: SimClock, goals: list[str], pause_s: float = 0.3):
    async def handler(goal: Text, ctx) -> Text:
        goals.append(goal.data)
        first = f"You said: {goal.data}"
        ctx.feedback(Text(first))
        await clock.sleep(pause_s)
        second = "The library is on the first floor."
        ctx.feedback(Text(second))
        return Text(f"{first} {second}")

    bus.actions.serve(CONVERSE, handler)


def is_subsequence(needle: Sequence[object], hay: Sequence[object]) -> bool:
    it = iter(hay)
    return all(any(x is y for y in it) for x in needle)


async def test_full_turn_with_fake_brain(voice_settings, models, say16k):
    room = Room(voice_settings, models)
    goals: list[str] = []
    echo_brain(room.bus, room.clock, goals)
    room.mic.inject(np.concatenate([silence(0.6), say16k("Hey Jarvis."), silence(0.6),
                                    say16k("Where is the library?"), silence(0.5)]))
    async with room:
        await room.until(lambda: room.latency and room.idle(), "the turn to end")
        # The idle face is published as the pipeline goes idle; it reaches room.ui later.
        await room.until(lambda: room.ui[-1].phase is Phase.IDLE, "the idle face")
    assert goals
    assert "library" in goals[0].lower()
    assert room.heard == goals
    phases = room.phases()
    assert is_subsequence(
        [Phase.IDLE, Phase.LISTENING, Phase.THINKING, Phase.SPEAKING, Phase.LISTENING, Phase.IDLE],
        phases,
    ), phases
    # The face saw the mouth move, the transcript and the reply.
    assert max(u.tts_viseme for u in room.ui) > 0.3
    assert any("library" in u.asr_final.lower() for u in room.ui)
    assert any("first floor" in u.llm_tokens for u in room.ui)
    # Both sentences were spoken, as audio chunks for the web pages and on the speaker.
    assert room.pipeline.mouth.sentences_spoken >= 2
    assert len(room.speaker.utterances) == 1
    spoken_s = sum(len(c.pcm) // 2 / c.sample_rate for c in room.audio)
    assert spoken_s == pytest.approx(room.speaker.seconds_played, rel=1e-6)
    assert room.audio[-1].final
    assert room.pipeline.early_transcripts == 1  # Whisper started on the pause
    lat = room.latency[0]
    assert 0 < lat.end_of_speech <= lat.stt_done <= lat.first_token <= lat.first_audio
    assert not math.isnan(lat.reply_delay_s)


@pytest.mark.parametrize("head", [True, False])
async def test_wakes_in_a_noisy_hallway_thanks_to_the_head(voice_settings, models, head):
    """A visitor (espeak-ng en-us+m3, 140 wpm) says "Hey Jarvis" in a hallway whose noise
    is 5 dB under the voice: with the wake head the robot starts listening; without it the
    same audio leaves it idle."""
    from sage_robot.voice.audio_io import resample
    from sage_robot.voice.tts import EspeakEngine

    es = EspeakEngine("en-us+m3", 140)
    visitor = resample(es.synthesize_sentence("Hey Jarvis."), es.sample_rate, 16000)
    rms = float(np.sqrt(np.mean(visitor.astype(np.float64) ** 2)))
    settings = voice_settings if head else voice_settings.model_copy(update={"wake_heads": {}})
    room = Room(settings, models, noise_rms=rms / 10 ** (5 / 20))
    audio = np.concatenate([silence(1.0), visitor, silence(1.0)])
    end = room.clock.now() + len(audio) / 16000 + 0.5  # sim time: the mic is in lockstep
    room.mic.inject(audio)
    async with room:
        await room.until(lambda: room.clock.now() > end or Phase.LISTENING in room.phases(),
                         "the visitor's audio to be heard")  # fmt: skip
    assert (Phase.LISTENING in room.phases()) is head, room.phases()


async def test_without_a_brain_it_says_so(voice_settings, models, say16k):
    room = Room(voice_settings, models)
    room.mic.inject(np.concatenate([silence(0.5), say16k("Hey Jarvis."), silence(0.5),
                                    say16k("What time is it?"), silence(0.5)]))
    async with room:
        await room.until(lambda: room.latency and room.idle(), "the turn to end")
    assert room.heard, "the visitor was heard"
    assert any(u.error_msg == "brain not running" for u in room.ui)
    # What it said is the "no brain" sentence: transcribe the speaker's output.
    pcm, rate = room.speaker.utterances[-1]
    from sage_robot.voice.audio_io import resample

    text = models.stt.transcribe(resample(pcm, rate, 16000)).text.lower()
    assert "brain" in text, (text, NO_BRAIN)
    assert "not running" in text, (text, NO_BRAIN)


async def test_say_topic_is_spoken_and_own_voice_does_not_wake(voice_settings, models):
    """The robot says the wake phrase itself; the echo reaches the mic; it must not wake."""
    room = Room(voice_settings, models)
    async with room:
        room.bus.publish(SAY, Text("Welcome! Say hey Jarvis, hey Jarvis, to talk to me."))
        await room.until(lambda: room.speaker.utterances and room.idle(), "the welcome")
        await room.clock.sleep(1.0)
    assert room.pipeline.mouth.utterances == 1
    assert room.pipeline.self_echoes_ignored >= 1, "the echo did score as a wake word"
    assert room.pipeline.turns == 0
    assert room.pipeline.barge_ins == 0
    assert Phase.LISTENING not in room.phases()


AEC_RESIDUAL_GAIN = 0.1  # echo left after the XVF3800's echo canceller (about -20 dB)


async def test_barge_in_cancels_the_reply(voice_settings, models, say16k):
    """A visitor says the wake word while the robot talks: the reply and the goal stop.
    (Over the full, uncancelled echo of the seed's speakerphone no detector hears a visitor
    reliably; the room here has the mic array's echo cancellation.)"""
    room = Room(voice_settings, models, echo_gain=AEC_RESIDUAL_GAIN)
    goals: list[str] = []
    cancelled: list[bool] = []

    async def long_brain(goal: Text, ctx) -> Text:
        goals.append(goal.data)
        try:
            for i in range(8):
                ctx.feedback(Text(f"This is sentence number {i + 1} of a very long answer."))
                await room.clock.sleep(0.2)
            await room.clock.sleep(60)
        except asyncio.CancelledError:
            cancelled.append(True)
            raise
        return Text("done")

    room.bus.actions.serve(CONVERSE, long_brain)
    room.mic.inject(np.concatenate([silence(0.5), say16k("Hey Jarvis."), silence(0.5),
                                    say16k("Tell me a story."), silence(0.5)]))
    async with room:
        await room.until(lambda: room.pipeline.mouth.speaking, "the reply to start")
        await room.clock.sleep(1.5)
        room.mic.inject(np.concatenate([say16k("Hey Jarvis."), silence(0.3),
                                        say16k("Stop."), silence(0.5)]))  # fmt: skip
        await room.until(lambda: room.pipeline.barge_ins >= 1, "the barge-in")
    assert cancelled == [True], "the brain's goal was cancelled"
    assert room.speaker.aborted >= 1
    assert room.pipeline.mouth.sentences_spoken < 8


async def test_face_shows_navigating_while_idle(voice_settings, models, say16k):
    """The navigator's state (/nav/state) puts the resting face into "navigating"; a
    conversation during the drive takes precedence; the end of navigation gives "idle"."""
    room = Room(voice_settings, models)
    goals: list[str] = []
    echo_brain(room.bus, room.clock, goals)
    async with room:
        room.bus.publish(NAV_STATE, NavigateFeedback(NavState.PLANNING, "library", 40.0, 80.0))
        await room.until(lambda: room.ui[-1].phase is Phase.NAVIGATING, "navigating")
        room.bus.publish(NAV_STATE, NavigateFeedback(NavState.DRIVING, "library", 39.0, 78.0))
        room.mic.inject(np.concatenate([silence(0.5), say16k("Hey Jarvis."), silence(0.6),
                                        say16k("Where is the library?"), silence(0.5)]))
        await room.until(lambda: room.latency and room.idle(), "the turn to end")
        # Back to the drive after the turn. The pipeline is idle as it publishes that face,
        # which reaches room.ui through the bus's subscriber queue: wait for it, bounded.
        await room.until(lambda: room.ui[-1].phase is Phase.NAVIGATING, "navigating after the turn")
        room.bus.publish(NAV_STATE, NavigateFeedback(NavState.IDLE, "library"))
        await room.until(lambda: room.ui[-1].phase is Phase.IDLE, "idle after arrival")
    assert goals
    assert "library" in goals[0].lower()
    phases = room.phases()
    assert is_subsequence(
        [Phase.IDLE, Phase.NAVIGATING, Phase.LISTENING, Phase.THINKING, Phase.SPEAKING,
         Phase.NAVIGATING, Phase.IDLE],
        phases,
    ), phases
    # No "navigating" in the middle of the conversation (wake word → reply spoken).
    talk = phases[phases.index(Phase.LISTENING):phases.index(Phase.SPEAKING) + 1]
    assert Phase.NAVIGATING not in talk, phases


class _MumbleStt:
    """The real recognizer, but the visitor mumbled: nothing is understood (Whisper gives an
    empty transcript for a cough or a mumble; a real recording of one is not at hand)."""

    def __init__(self, stt) -> None:
        self.stt = stt

    def transcribe(self, pcm, *args):
        heard = self.stt.transcribe(pcm, *args)
        return type(heard)("", heard.confidence, heard.no_speech_prob, heard.duration_s)


async def test_nothing_understood_goes_back_to_resting(voice_settings, models, say16k):
    """An empty transcript ends the turn: the face rests and the next wake word is a new turn
    (before, the pipeline stayed busy and the face kept "thinking")."""
    room = Room(voice_settings, models)
    goals: list[str] = []
    echo_brain(room.bus, room.clock, goals)
    mumble = _MumbleStt(room.pipeline.turn.stt)
    # the final and the early transcript; a stand-in for SpeechToText (only transcribe is called)
    room.pipeline.turn.stt = room.pipeline.live.stt = mumble  # type: ignore[assignment]
    room.mic.inject(np.concatenate([silence(0.5), say16k("Hey Jarvis."), silence(0.5),
                                    say16k("Where is the library?"), silence(0.8)]))
    async with room:
        await room.until(lambda: room.latency and room.idle(), "the turn to end")
        await room.until(lambda: room.ui[-1].phase is Phase.IDLE, "the resting face")
    assert not goals  # nothing was sent to the brain
    assert room.pipeline.state is State.IDLE
