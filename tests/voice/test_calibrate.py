"""`sage voice wake calibrate`: a custom model's threshold and patience from recordings
made with the robot's Piper voice and noise, checked against the real detector."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from sage_robot.cli.main import main
from sage_robot.core.audio import FRAME_SAMPLES, SAMPLE_RATE_HZ
from sage_robot.core.config import load_profile
from sage_robot.core.config.loader import default_profile_path
from sage_robot.voice.audio_io import resample, write_wav
from sage_robot.voice.calibrate import choose, count_detections, held, padded
from sage_robot.voice.wake import OpenWakeWordEngine, WakeDetector, bundled_wake_models

from .conftest import noise, silence

POSITIVE_TEXTS = ("Hey Mycroft.", "Hey Mycroft, where is the lab?")
POSITIVE_SPEEDS = (0.85, 1.0, 1.25)  # Piper length scales
POSITIVE_SNRS_DB = (None, 5.0)
NEGATIVE_TEXTS = ("Welcome to the engineering building.", "Hey, my friend is over there.",
                  "Microsoft builds software.", "Please follow me to the next stop.")  # fmt: skip


@pytest.fixture(scope="module")
def recordings(tmp_path_factory, models):
    """Folders of positive clips and negative recordings (WAV), as the owners would make."""
    from sage_robot.bench.voice_wake import noisy

    root = tmp_path_factory.mktemp("wake_rec")
    pos, neg = root / "pos", root / "neg"
    pos.mkdir()
    neg.mkdir()
    piper = models.speech.engine
    k = 0
    for speed in POSITIVE_SPEEDS:
        piper.length_scale = speed
        for text in POSITIVE_TEXTS:
            pcm = resample(piper.synthesize_sentence(text), piper.sample_rate, SAMPLE_RATE_HZ)
            for snr in POSITIVE_SNRS_DB:
                write_wav(pos / f"p{k:02d}.wav", noisy(pcm, snr, np.random.default_rng(k)), SAMPLE_RATE_HZ)
                k += 1
    piper.length_scale = None
    talk = [resample(piper.synthesize_sentence(t), piper.sample_rate, SAMPLE_RATE_HZ) for t in NEGATIVE_TEXTS]
    write_wav(neg / "talk.wav", np.concatenate([x for t in talk for x in (t, silence(0.4))]), SAMPLE_RATE_HZ)
    write_wav(neg / "noise.wav", noise(6.0, 900, seed=4), SAMPLE_RATE_HZ)
    return pos, neg


def test_calibrate_writes_the_profile_and_its_rates_are_the_detectors(recordings, tmp_path, capsys):
    pos, neg = recordings
    profile = tmp_path / "robot.yaml"
    shutil.copy(default_profile_path(), profile)
    model = str(bundled_wake_models()["hey_mycroft"])
    argv = ["--profile", str(profile), "voice", "wake", "calibrate", "--model", model,
            "--positives", str(pos), "--negatives", str(neg), "--json"]  # fmt: skip
    assert main(argv) == 0
    cal = json.loads(capsys.readouterr().out)
    assert cal["profile"] == str(profile)
    assert cal["meets_target"]
    assert cal["band"][0] <= cal["threshold"] <= cal["band"][1]
    assert cal["false_accepts"] == 0
    vs = load_profile(profile).voice
    assert vs.wake_model_thresholds["hey_mycroft"] == cal["threshold"]
    assert vs.wake_model_patience["hey_mycroft"] == cal["patience"]
    assert vs.wake_model_thresholds["hey_jarvis"] == load_profile().voice.wake_model_thresholds["hey_jarvis"]
    # The profile's real detector with the written setting misses and wakes exactly as reported.
    vs = vs.model_copy(update={"wake_models": (model,), "wake_heads": {}})
    engine = OpenWakeWordEngine([model])
    misses = 0
    for clip in sorted(pos.iterdir()):
        from sage_robot.voice.audio_io import load_audio

        engine.reset()
        misses += not WakeDetector.from_settings(engine, vs).feed(padded(load_audio(clip)))
    assert misses == cal["false_rejects"]
    assert cal["false_reject_rate"] == pytest.approx(misses / cal["positives"], abs=1e-4)
    assert cal["false_reject_rate"] <= 0.5, "the model should hear most of its own phrase"


def test_choose_takes_the_middle_of_the_band_and_counts_with_refractory():
    """Scripted scores: positives peak at 0.7 and 0.8 (two frames), negatives at 0.3 once and
    at 0.6 for one frame: patience 1 would accept it, patience 2 does not."""
    pos = [np.array([0, 0.7, 0.7, 0]), np.array([0, 0.8, 0.8, 0.1])]
    neg = [np.array([0.0] * 50 + [0.3, 0.6, 0.3] + [0.0] * 50)]
    strict = choose("m", pos, neg, max_fa_per_hour=0.0)
    assert (strict.patience, strict.false_rejects, strict.false_accepts) == (1, 0, 0)
    assert strict.band == (0.61, 0.7)
    assert strict.threshold == pytest.approx(0.65, abs=0.01)
    assert held(np.array([0.2, 0.6, 0.5, 0.9]), 1, 2).tolist() == [0.0, 0.2, 0.5, 0.5]
    # two bursts 1 s apart are one detection (2 s refractory), 3 s apart two
    burst = [0.9] * 3
    close = np.array([0.0] * 5 + burst + [0.0] * 10 + burst + [0.0] * 5)
    far = np.array([0.0] * 5 + burst + [0.0] * 35 + burst + [0.0] * 5)
    for stream, expected in ((close, 1), (far, 2)):
        assert count_detections(held(stream, 1, 2), 0.5, 2.0) == expected
        # the detector agrees on those counts
        det = WakeDetector(_Replay(stream), threshold=0.5, patience=2, refractory_s=2.0)
        assert len(det.feed(np.zeros(len(stream) * FRAME_SAMPLES, np.int16))) == expected


class _Replay:
    names = ("m",)

    def __init__(self, scores: np.ndarray) -> None:
        self.scores = list(scores)

    def score(self, frame: np.ndarray) -> dict[str, float]:
        return {"m": float(self.scores.pop(0)) if self.scores else 0.0}

    def reset(self) -> None:
        pass


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--positives", "/nonexistent"], "calibrate needs --positives DIR and --negatives DIR"),
        (["--positives", "/nonexistent", "--negatives", "/tmp"], "not a folder"),
    ],
)
def test_calibrate_bad_input_is_one_clear_line(extra, message, capsys):
    assert main(["voice", "wake", "calibrate", "--model", "hey_jarvis", *extra]) == 2
    err = capsys.readouterr().err
    assert message in err
    assert len(err.strip().splitlines()) == 1
