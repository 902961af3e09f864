"""Voice test fixtures: real models, each loaded once per session (they take seconds)."""

from __future__ import annotations

import functools
import os
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("HF_HUB_OFFLINE", "1")

pytest.importorskip("faster_whisper", reason="voice tests need: pip install 'sage-robot[voice]'")
pytest.importorskip("piper", reason="voice tests need: pip install 'sage-robot[voice-gpl]'")

from sage_robot.core.audio import SAMPLE_RATE_HZ
from sage_robot.core.config.areas import VoiceSettings
from sage_robot.voice.audio_io import resample

POCKETSPHINX = Path("/usr/share/pocketsphinx/test/data")


@pytest.fixture(scope="session")
def voice_settings() -> VoiceSettings:
    # Both bundled models: the default profile has hey_jarvis only, alexa is opt-in.
    return VoiceSettings(tts_deterministic=True, wake_models=("hey_jarvis", "alexa"))


@pytest.fixture(scope="session")
def models(voice_settings):
    from sage_robot.voice.node import VoiceModels

    return VoiceModels.load(voice_settings)


@pytest.fixture(scope="session")
def say16k(models):
    """Text → the robot's (deterministic) voice at 16 kHz int16, cached per text."""

    @functools.cache
    def render(text: str) -> np.ndarray:
        speech = models.speech
        pcm = speech.synthesize(text)
        return resample(pcm, speech.sample_rate, SAMPLE_RATE_HZ)

    return render


def silence(seconds: float) -> np.ndarray:
    return np.zeros(round(seconds * SAMPLE_RATE_HZ), dtype=np.int16)


def noise(seconds: float, rms: float = 30.0, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.clip(rng.normal(0, rms, round(seconds * SAMPLE_RATE_HZ)), -32768, 32767).astype(np.int16)


def neutral_and_noise(say16k) -> np.ndarray:
    """Every neutral sentence of test_wake in the robot's voice, then white noise."""
    from .test_wake import NEUTRAL

    return np.concatenate([x for s in NEUTRAL for x in (say16k(s), silence(0.3))]
                          + [noise(3, 800), noise(2, 2000, seed=1)])  # fmt: skip


def chunked_runs(
    engine, settings, audio: np.ndarray, key: str
) -> list[tuple[list[tuple[str, float, float]], float]]:
    """The profile detector over ``audio`` fed in 80 ms, 333- and 4096-sample chunks:
    per run, its detections (model, time, score) and the best smoothed score of ``key``."""
    from sage_robot.core.audio import FRAME_SAMPLES
    from sage_robot.voice.wake import WakeDetector

    results = []
    for chunk in (FRAME_SAMPLES, 333, 4096):
        engine.reset()
        det = WakeDetector.from_settings(engine, settings)
        found = []
        for i in range(0, len(audio), chunk):
            found += det.feed(audio[i : i + chunk])
        results.append(([(d.model, d.time_s, round(d.score, 6)) for d in found],
                        round(det.max_smoothed[key], 6)))  # fmt: skip
    return results


@pytest.fixture
def pocketsphinx_data() -> Path:
    if not (POCKETSPHINX / "goforward.raw").is_file():
        pytest.skip("Debian's pocketsphinx-testdata is not installed (see scripts/apt-packages.txt)")
    return POCKETSPHINX
