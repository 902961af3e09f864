"""No invented text: unclear segments are dropped by the STT, and the pipeline does not act
on a transcript it is unsure of (it says it did not catch that, once)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from sage_robot.core.audio import SAMPLE_RATE_HZ
from sage_robot.voice.audio_io import resample
from sage_robot.voice.pipeline import State
from sage_robot.voice.stt import (
    COMPRESSION_RATIO_MAX,
    NO_SPEECH,
    UNCLEAR,
    compression_ratio,
    judge_segments,
    repeated_sentences,
)
from sage_robot.voice.turn import NOT_CAUGHT

from .conftest import silence
from .test_pipeline import Room, echo_brain

LOOP = "It's not used by the service."  # what tiny.en said 3 times over 30 s of noise (#22)


def seg(text: str, logprob: float = -0.3, no_speech: float = 0.1):
    return SimpleNamespace(text=text, start=0.0, end=1.0, avg_logprob=logprob, no_speech_prob=no_speech)


def test_judge_drops_loops_unsure_and_silent_segments():
    good = seg(" Where is the library?")
    assert judge_segments([good]) == ([good], "")
    assert judge_segments([seg(f" {LOOP} {LOOP} {LOOP}")]) == ([], UNCLEAR)
    looped = [seg(f" {LOOP}"), seg(f" {LOOP}"), seg(f" {LOOP}")]
    assert judge_segments(looped) == ([], UNCLEAR)
    assert judge_segments([seg(" Where is the lab?", logprob=-1.4)]) == ([], UNCLEAR)
    assert judge_segments([seg(" Thank you.", no_speech=0.9)]) == ([], NO_SPEECH)
    assert judge_segments([]) == ([], NO_SPEECH)
    kept, why = judge_segments([good, *looped])  # real speech beside a loop: the speech stays
    assert (kept, why) == ([good], "")
    assert compression_ratio("la " * 60) > COMPRESSION_RATIO_MAX > compression_ratio(good.text)
    # short repeats ("yes. yes.") are speech; a long sentence said twice is a loop
    assert repeated_sentences(["Yes. Yes. Go forward ten meters."]) == set()
    assert repeated_sentences(["Go forward ten meters. Go forward ten meters!"]) == {"go forward ten meters"}


def test_thirty_seconds_of_babble_in_noise_gives_no_text(models):
    """Six espeak-ng talkers over each other in white noise (speech-like, nothing clear)."""
    from sage_robot.voice.tts import EspeakEngine

    n = 30 * SAMPLE_RATE_HZ
    rng = np.random.default_rng(22)
    babble = np.zeros(n)
    for voice in ("en-us", "en-gb", "en-us+f3", "en-us+m3", "en-gb-scotland", "en-029"):
        es = EspeakEngine(voice, 175)
        pcm = resample(es.synthesize_sentence("The dean's office is at the end of this corridor and the "
                                              "lab is upstairs past the glass doors."),
                       es.sample_rate, SAMPLE_RATE_HZ).astype(np.float64)  # fmt: skip
        src = np.tile(pcm, n // len(pcm) + 2)
        off = int(rng.integers(0, len(pcm)))
        babble += src[off : off + n]
    audio = np.clip(babble * 0.5 + rng.normal(0, 3000, n), -32768, 32767).astype(np.int16)
    result = models.stt.transcribe(audio)
    assert result.text == "", result.as_dict()
    assert result.rejected in (NO_SPEECH, UNCLEAR)


def test_real_speech_is_kept(models, pocketsphinx_data):
    from sage_robot.voice.audio_io import load_audio

    result = models.stt.transcribe(load_audio(pocketsphinx_data / "goforward.raw"))
    assert result.text.lower().startswith("go forward")
    assert (result.rejected, result.dropped) == ("", 0)


async def test_unsure_transcript_is_not_acted_on(voice_settings, models, say16k):
    """With a confidence floor no transcript reaches, the robot never asks the brain: it
    says it did not catch that and listens again; unsure a second time, it stays quiet."""
    settings = voice_settings.model_copy(update={"stt_min_confidence": 0.999})
    room = Room(settings, models)
    goals: list[str] = []
    echo_brain(room.bus, room.clock, goals)
    pipe = room.pipeline
    room.mic.inject(np.concatenate([silence(0.5), say16k("Hey Jarvis."), silence(0.5),
                                    say16k("Where is the library?"), silence(0.5)]))  # fmt: skip
    async with room:
        await room.until(lambda: pipe.not_caught == 1 and room.speaker.utterances
                         and pipe.state is State.LISTENING and not pipe.mouth.speaking,
                         "the robot to ask again and listen")  # fmt: skip
        room.mic.inject(np.concatenate([say16k("Where is the library?"), silence(0.5)]))
        await room.until(lambda: pipe.not_caught == 2 and room.idle(), "the second unsure turn to end")
    assert goals == [], "an unsure transcript reached the brain"
    assert room.heard == []
    assert len(room.speaker.utterances) == 1, "it asked again more than once"
    pcm, rate = room.speaker.utterances[0]
    said = models.stt.transcribe(resample(pcm, rate, SAMPLE_RATE_HZ)).text.lower()
    assert "catch" in said, (said, NOT_CAUGHT)
