"""Custom wake models (loaded by path) judged as openWakeWord judges them."""

from __future__ import annotations

import contextlib
import io

import numpy as np
import pytest

from sage_robot.core.audio import FRAME_SAMPLES
from sage_robot.voice.wake import (
    CUSTOM_PATIENCE,
    CUSTOM_THRESHOLD,
    OpenWakeWordEngine,
    WakeDetector,
    bundled_wake_models,
)

from .conftest import noise, silence

OWW_THRESHOLD = 0.5  # openWakeWord's README: "a threshold of 0.5 ... for most models"
UNSURE_BAND = 0.05  # clips whose reference score is this close to 0.5 are not compared


def oww_reference(model_path: str, audio: np.ndarray) -> float:
    """openWakeWord's own loop: a fresh Model fed 80 ms frames; its best frame score."""
    from openwakeword.model import Model

    from sage_robot.voice.wake import _bundled_dir

    base = _bundled_dir()
    with contextlib.redirect_stdout(io.StringIO()):
        model = Model(wakeword_models=[model_path], inference_framework="onnx",
                      melspec_model_path=str(base / "melspectrogram.onnx"),
                      embedding_model_path=str(base / "embedding_model.onnx"))  # fmt: skip
    best = 0.0
    for i in range(0, len(audio) - FRAME_SAMPLES + 1, FRAME_SAMPLES):
        best = max(best, *model.predict(audio[i : i + FRAME_SAMPLES]).values())
    return float(best)


@pytest.fixture(scope="module")
def mycroft_path() -> str:
    return str(bundled_wake_models()["hey_mycroft"])


def test_custom_model_defaults_to_openwakeword_conventions(mycroft_path, voice_settings):
    engine = OpenWakeWordEngine([mycroft_path, "alexa"])
    assert engine.custom_names == {"hey_mycroft"}
    det = WakeDetector.from_settings(engine, voice_settings)
    assert det.thresholds["hey_mycroft"] == CUSTOM_THRESHOLD == OWW_THRESHOLD
    assert det.patiences["hey_mycroft"] == CUSTOM_PATIENCE == 1
    assert det.smoothings["hey_mycroft"] == 1
    # a bundled model keeps the profile's settings
    assert det.thresholds["alexa"] == voice_settings.wake_model_thresholds["alexa"]
    # the profile overrides the convention when it names the model
    tuned = voice_settings.model_copy(update={"wake_model_thresholds": {"hey_mycroft": 0.7},
                                              "wake_model_patience": {"hey_mycroft": 3}})  # fmt: skip
    det = WakeDetector.from_settings(engine, tuned)
    assert (det.thresholds["hey_mycroft"], det.patiences["hey_mycroft"]) == (0.7, 3)


def test_custom_model_accepts_what_openwakeword_accepts(mycroft_path, voice_settings, models):
    """Renderings of "Hey Mycroft" (speeds, noise) and other speech: SAGE's profile detector
    with a path-loaded model wakes on exactly the clips openWakeWord's own loop accepts."""
    from sage_robot.bench.voice_wake import noisy
    from sage_robot.core.audio import SAMPLE_RATE_HZ
    from sage_robot.voice.audio_io import resample

    piper = models.speech.engine
    clips = []
    renderings = ((0.9, None, "Hey Mycroft."), (1.2, None, "Hey Mycroft, where is the lab?"),
                  (1.0, 10.0, "Hey Mycroft."), (1.0, 0.0, "Hey Mycroft."),
                  (1.0, None, "Hey, my crofter is here."), (1.0, None, "Welcome to the lab."))
    for speed, snr, text in renderings:
        piper.length_scale = speed
        pcm = resample(piper.synthesize_sentence(text), piper.sample_rate, SAMPLE_RATE_HZ)
        clips.append(np.concatenate([silence(1.0), noisy(pcm, snr, np.random.default_rng(3)), silence(1.0)]))
    piper.length_scale = None
    clips.append(noise(3.0, 800))
    engine = OpenWakeWordEngine([mycroft_path])
    ours, theirs = [], []
    for clip in clips:
        engine.reset()
        woke = bool(WakeDetector.from_settings(engine, voice_settings).feed(clip))
        ref = oww_reference(mycroft_path, clip)
        if abs(ref - OWW_THRESHOLD) > UNSURE_BAND:
            ours.append(woke)
            theirs.append(ref >= OWW_THRESHOLD)
    assert any(theirs), "openWakeWord accepted none of the renderings: the test says nothing"
    assert not all(theirs)
    assert ours == theirs
