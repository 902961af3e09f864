"""Wake words with the real openWakeWord models on the robot's real (Piper) voice."""

from __future__ import annotations

import shutil
import threading

import numpy as np
import pytest

from sage_robot.core.audio import FRAME_SAMPLES, SAMPLE_RATE_HZ
from sage_robot.core.errors import ConfigError
from sage_robot.voice.audio_io import resample
from sage_robot.voice.wake import OpenWakeWordEngine, WakeDetector, bundled_wake_models

from .conftest import noise, silence

WAIT_S = 30.0  # bound on every wait for a thread (real seconds)

NEUTRAL = [
    "Welcome to the engineering building.",
    "The robotics lab is on the first floor, past the glass doors.",
    "Travis and Harvey are working on the drone.",
    "Please follow me and mind the step.",
    "Alex sat on the bench outside the cafe.",
]


def frame_scores(engine, audio: np.ndarray, chunks: list[int]) -> np.ndarray:
    """Feed ``audio`` cut into pieces of the given sizes (cycled); every frame's scores."""
    engine.reset()
    det = WakeDetector(engine, keep_scores=True)
    i = k = 0
    while i < len(audio):
        n = chunks[k % len(chunks)]
        det.feed(audio[i : i + n])
        i, k = i + n, k + 1
    return np.array([[s["hey_jarvis"], s["alexa"]] for s in det.scores])


def test_hey_jarvis_is_detected_once(models, say16k):
    audio = np.concatenate([silence(0.5), say16k("Hey Jarvis."), silence(1.5)])
    models.wake.reset()
    det = WakeDetector(models.wake, threshold=0.6, refractory_s=2.0)
    found = det.feed(audio)
    assert [d.model for d in found] == ["hey_jarvis"]
    assert 0.5 < found[0].time_s <= len(audio) / 16000
    assert det.max_scores["alexa"] < 0.1


def test_alexa_is_detected_by_its_own_model(models, say16k):
    models.wake.reset()
    det = WakeDetector(models.wake)
    found = det.feed(np.concatenate([silence(0.5), say16k("Alexa."), silence(1.5)]))
    assert [d.model for d in found] == ["alexa"]


def test_refractory_merges_one_phrase_but_not_two(models, say16k):
    phrase = say16k("Hey Jarvis.")
    models.wake.reset()
    det = WakeDetector(models.wake, refractory_s=2.0)
    once = det.feed(np.concatenate([silence(0.5), phrase, silence(0.5)]))
    twice = det.feed(np.concatenate([silence(2.5), phrase, silence(1.0)]))
    assert len(once) == 1
    assert len(twice) == 1
    assert twice[0].time_s - once[0].time_s > 2.0


def test_score_does_not_depend_on_chunk_size(models, say16k):
    """STYLE 11: the same audio in any chunking gives the same score for every frame."""
    audio = np.concatenate([silence(0.4), say16k("Hey Jarvis."), noise(0.6)])
    reference = frame_scores(models.wake, audio, [FRAME_SAMPLES])
    assert len(reference) == len(audio) // FRAME_SAMPLES
    assert reference[:, 0].max() > 0.6
    for chunks in ([160], [512], [1000], [4000], [37, 2000, 777, 1280, 5]):
        np.testing.assert_allclose(frame_scores(models.wake, audio, chunks), reference, atol=1e-6)


def test_chunked_detections_match_exactly(models, say16k):
    audio = np.concatenate([silence(0.4), say16k("Hey Jarvis."), silence(0.8)])
    results = []
    for chunk in (FRAME_SAMPLES, 333, 4096):
        models.wake.reset()
        det = WakeDetector(models.wake)
        found = []
        for i in range(0, len(audio), chunk):
            found += det.feed(audio[i : i + chunk])
        results.append([(d.model, d.time_s, round(d.score, 6)) for d in found])
    assert results[0]
    assert results[0] == results[1] == results[2]


def test_no_wake_on_neutral_sentences_and_noise(models, say16k):
    audio = np.concatenate([x for s in NEUTRAL for x in (say16k(s), silence(0.3))] + [noise(3, 800)])
    models.wake.reset()
    det = WakeDetector(models.wake)
    assert det.feed(audio) == []
    assert max(det.max_scores.values()) < 0.6


class ScriptedEngine:
    """Plays back a list of scores, one per frame (the detector's logic alone)."""

    names = ("w",)

    def __init__(self, scores: list[float]) -> None:
        self.scores = list(scores)

    def score(self, frame: np.ndarray) -> dict[str, float]:
        return {"w": self.scores.pop(0) if self.scores else 0.0}

    def reset(self) -> None:
        pass


@pytest.mark.parametrize(
    ("scores", "patience", "frames"),
    [
        ([0, 0.9, 0, 0, 0], 2, []),  # a one-frame spike
        ([0, 0.9, 0, 0, 0], 1, [2]),
        ([0, 0.7, 0.8, 0.9, 0.9, 0], 2, [3]),  # reported when the run reaches 2 frames
        ([0.9] * 3 + [0] * 10 + [0.9] * 3, 2, [2]),  # 13 frames apart < 2 s refractory
        ([0.9] * 3 + [0] * 30 + [0.9] * 3, 2, [2, 35]),  # 2.6 s apart: two phrases
    ],
)
def test_threshold_patience_refractory(scores, patience, frames):
    det = WakeDetector(ScriptedEngine(scores), threshold=0.6, refractory_s=2.0, patience=patience)
    found = det.feed(np.zeros(len(scores) * FRAME_SAMPLES, np.int16))
    assert [round(d.time_s / 0.08) for d in found] == frames


def test_custom_onnx_model_loads_by_path(tmp_path, say16k):
    """A custom model (the seed's "hey sage") is any openWakeWord .onnx file given by path."""
    custom = tmp_path / "hey_sage.onnx"
    shutil.copy(bundled_wake_models()["hey_jarvis"], custom)
    engine = OpenWakeWordEngine([str(custom)])
    assert engine.names == ("hey_sage",)
    found = WakeDetector(engine).feed(np.concatenate([silence(0.5), say16k("Hey Jarvis."), silence(1)]))
    assert [d.model for d in found] == ["hey_sage"]


def test_bad_wake_models_are_clear_errors(tmp_path):
    with pytest.raises(ConfigError, match=r"unknown wake model 'hey_nobody'.*bundled: .*hey_jarvis"):
        OpenWakeWordEngine(["hey_nobody"])
    with pytest.raises(ConfigError, match="no such file"):
        OpenWakeWordEngine([str(tmp_path / "missing.onnx")])
    broken = tmp_path / "broken.onnx"
    broken.write_bytes(b"not a model")
    with pytest.raises(ConfigError, match="cannot load wake models"):
        OpenWakeWordEngine([str(broken)])
    with pytest.raises(ConfigError, match="at least one"):
        OpenWakeWordEngine([])


class TwoModelEngine:
    """Scripted scores for two models: per-model thresholds and patience apply separately."""

    names = ("a", "b")

    def __init__(self, scores: list[tuple[float, float]]) -> None:
        self.scores = list(scores)

    def score(self, frame: np.ndarray) -> dict[str, float]:
        a, b = self.scores.pop(0) if self.scores else (0.0, 0.0)
        return {"a": a, "b": b}

    def reset(self) -> None:
        pass


def test_per_model_threshold_and_patience():
    scores = [(0.0, 0.0), (0.45, 0.45), (0.0, 0.7), (0.0, 0.7), (0.0, 0.0)]
    det = WakeDetector(TwoModelEngine(scores), threshold=0.6, patience=2,
                       model_thresholds={"a": 0.4}, model_patience={"a": 1})  # fmt: skip
    found = det.feed(np.zeros(len(scores) * FRAME_SAMPLES, np.int16))
    assert [(d.model, round(d.time_s / 0.08)) for d in found] == [("a", 2), ("b", 4)]
    assert det.thresholds == {"a": 0.4, "b": 0.6}
    assert det.patiences == {"a": 1, "b": 2}
    with pytest.raises(ValueError, match="patience"):
        WakeDetector(TwoModelEngine([]), model_patience={"b": 0})
    with pytest.raises(ValueError, match="threshold of a"):
        WakeDetector(TwoModelEngine([]), model_thresholds={"a": 1.5})


def test_smoothing_averages_scores_before_the_threshold():
    """A moderate score held over frames passes; a one-frame spike of the same height
    does not (mean over the last 3 frames)."""
    held = [0.0, 0.35, 0.35, 0.35, 0.0, 0.0]
    spike = [0.0, 0.0, 0.9, 0.0, 0.0, 0.0]
    for scores, frames in ((held, [4]), (spike, [])):
        det = WakeDetector(ScriptedEngine(scores), threshold=0.32, patience=1, smoothing=3)
        found = det.feed(np.zeros(len(scores) * FRAME_SAMPLES, np.int16))
        assert [round(d.time_s / 0.08) for d in found] == frames
        assert det.max_smoothed["w"] == pytest.approx(max(scores) if scores is held else 0.3)
    with pytest.raises(ValueError, match="smoothing"):
        WakeDetector(ScriptedEngine([]), model_smoothing={"w": 0})


def test_profile_alexa_wakes_on_alexa_not_on_alex(models, voice_settings, say16k):
    """alexa's profile settings (0.8, 2-frame mean, 3 frames): a spoken "Alexa" wakes it,
    the bench's confusable "Alex sat on the bench outside" does not."""
    models.wake.reset()
    det = WakeDetector.from_settings(models.wake, voice_settings)
    assert det.smoothings["alexa"] > 1
    assert det.patiences["alexa"] > 1
    found = det.feed(np.concatenate([silence(0.5), say16k("Alexa, where is the cafe?"), silence(1)]))
    assert [d.model for d in found] == ["alexa"]
    models.wake.reset()
    det = WakeDetector.from_settings(models.wake, voice_settings)
    assert det.feed(np.concatenate([silence(0.5), say16k("Alex sat on the bench outside."),
                                    silence(1)])) == []  # fmt: skip


def test_profile_detector_no_wake_on_neutral_and_noise(models, voice_settings, say16k):
    """The profile's per-model settings (hey_jarvis 0.25 on a 5-frame mean) stay silent on
    other speech and noise, and still hear an espeak-ng "hey jarvis" in noise."""
    from sage_robot.bench.voice_wake import noisy as add_noise
    from sage_robot.voice.tts import EspeakEngine

    audio = np.concatenate([x for s in NEUTRAL for x in (say16k(s), silence(0.3))] + [noise(3, 800)])
    models.wake.reset()
    det = WakeDetector.from_settings(models.wake, voice_settings)
    assert det.thresholds["hey_jarvis"] < voice_settings.wake_threshold
    assert det.feed(audio) == []
    es = EspeakEngine("en-gb", 140)
    pcm = resample(es.synthesize_sentence("Hey Jarvis."), es.sample_rate, SAMPLE_RATE_HZ)
    models.wake.reset()
    det = WakeDetector.from_settings(models.wake, voice_settings)
    noisy = add_noise(pcm, 10.0, np.random.default_rng(1))
    found = det.feed(np.concatenate([silence(0.5), noisy, silence(1.0)]))
    assert [d.model for d in found] == ["hey_jarvis"]


def test_a_new_detector_does_not_hear_what_an_earlier_one_was_fed(models, voice_settings, say16k):
    """Pipelines built again on the same loaded models (a restart, the tests) share one
    engine: the wake word the last detector heard must not wake the next one."""
    first = WakeDetector.from_settings(models.wake, voice_settings)
    phrase = np.concatenate([silence(0.5), say16k("Hey Jarvis.")])
    cut = len(phrase) - FRAME_SAMPLES * 2  # stop just before the first detector would wake
    assert not first.feed(phrase[:cut])
    second = WakeDetector.from_settings(models.wake, voice_settings)
    assert not second.feed(silence(2.0))
    assert second.max_smoothed["hey_jarvis"] < 0.05


def test_a_reset_waits_for_a_score_in_progress(models, monkeypatch):
    """One engine serves every pipeline built on the loaded models: a new pipeline's reset
    must not interleave with the last frame a stopped one is still scoring in a worker
    thread (openWakeWord's buffers are not thread-safe)."""
    engine = models.wake
    model = engine._model
    events: list[str] = []
    inside, release = threading.Event(), threading.Event()
    predict, reset = model.predict, model.reset

    def slow_predict(frame):
        events.append("predict starts")
        inside.set()
        assert release.wait(WAIT_S)
        out = predict(frame)
        events.append("predict ends")
        return out

    def logged_reset():
        reset()
        events.append("reset")

    monkeypatch.setattr(model, "predict", slow_predict)
    monkeypatch.setattr(model, "reset", logged_reset)
    scorer = threading.Thread(target=engine.score, args=(np.zeros(FRAME_SAMPLES, dtype=np.int16),))
    scorer.start()
    assert inside.wait(WAIT_S)
    resetter = threading.Thread(target=engine.reset)
    resetter.start()
    resetter.join(0.2)  # it cannot finish while the score holds the engine
    release.set()
    scorer.join(WAIT_S)
    resetter.join(WAIT_S)
    assert not scorer.is_alive()
    assert not resetter.is_alive()
    assert events == ["predict starts", "predict ends", "reset"]
