"""Wake-word clips for ``sage bench voice``: synthesized "hey jarvis" / "alexa" (Piper at
several speeds, espeak-ng voices), clean, in white noise (also starting before the phrase) and
in the babble of other talkers; minutes of other speech and noise; and the scoring of false
rejects and false accepts. 16 kHz mono; scores through the profile's wake detector."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from sage_robot.core.audio import SAMPLE_RATE_HZ

POCKETSPHINX = Path("/usr/share/pocketsphinx/test/data")  # Debian's pocketsphinx-testdata

WAKE_PHRASES = ("Hey Jarvis.", "Hey Jarvis, where is the lab?")
ALEXA_PHRASES = ("Alexa.", "Alexa, where is the lab?")
WAKE_MODELS = ("hey_jarvis", "alexa")  # scored: the profile's hey_jarvis and the opt-in alexa
PIPER_SPEEDS = (0.8, 0.9, 1.0, 1.15, 1.3)  # length scales: < 1 faster
ESPEAK_VOICES = ("en-us", "en-us+f3", "en-gb", "en-us+m3")
ESPEAK_RATES = (140, 175)  # words per minute
SNRS_DB = (None, 15.0, 5.0)
WAKE_LEAD_S = 2.0  # noisy clips again, the noise starting this long before the phrase
WAKE_NOISE_SEED = 11  # clean, then white noise at these signal-to-noise ratios
BABBLE_SNRS_DB = (10.0, 5.0)  # four other talkers (a busy hallway) at these ratios
BABBLE_TALKERS = 4
BABBLE_SEED = 12

NEUTRAL = (
    "Welcome to the engineering building.", "The robotics lab is on the first floor.",
    "Please follow me to the next stop.", "This hallway leads to the lecture halls.",
    "The cafe serves coffee until four in the afternoon.", "Students build rockets here.",
    "Our senior design projects are on display.", "The elevator is to your left.",
    "Mind the step as we enter the workshop.", "The library has quiet study rooms upstairs.",
    "We have three machine shops and a clean room.", "Ask me anything about the college.",
    "The dean's office is at the end of this corridor.", "Turn right after the glass doors.",
    "Thank you for visiting, have a wonderful day.", "The solar car team meets on Tuesdays.",
    "Hey, are you coming with us?", "Jars of paint are stored in the art room.",
    "Travis and Harvey are working on the drone.", "Alex sat on the bench outside.",
)  # fmt: skip


def noisy(x: np.ndarray, snr_db: float | None, rng: np.random.Generator) -> np.ndarray:
    if snr_db is None:
        return x
    sig = float(np.sqrt(np.mean(x.astype(np.float64) ** 2))) + 1e-9
    noise = rng.normal(0.0, sig / 10 ** (snr_db / 20), len(x))
    return np.clip(x + noise, -32768, 32767).astype(np.int16)


def wake_sources(speech: Any, phrases: tuple[str, ...], quick: bool) -> list[tuple[str, np.ndarray]]:
    """Clean 16 kHz renderings: Piper at several speeds (each phrase), espeak-ng voices (first)."""
    from sage_robot.voice.audio_io import resample
    from sage_robot.voice.tts import EspeakEngine

    out: list[tuple[str, np.ndarray]] = []
    piper = speech.engine
    for speed in PIPER_SPEEDS[:2] if quick else PIPER_SPEEDS:
        piper.length_scale = speed
        for phrase in phrases:
            pcm = resample(piper.synthesize_sentence(phrase), piper.sample_rate, SAMPLE_RATE_HZ)
            out.append((f"piper x{speed} {phrase}", pcm))
    piper.length_scale = None
    for voice in ESPEAK_VOICES[: 1 if quick else None]:
        for wpm in ESPEAK_RATES:
            es = EspeakEngine(voice, wpm)
            pcm = resample(es.synthesize_sentence(phrases[0]), es.sample_rate, SAMPLE_RATE_HZ)
            out.append((f"espeak {voice} {wpm}wpm {phrases[0]}", pcm))
    return out


def white_clips(sources: list[tuple[str, np.ndarray]], lead_s: float = 0.0
                 ) -> list[tuple[str, np.ndarray]]:  # fmt: skip
    """Each source clean and in white noise at ``SNRS_DB`` (noise seeded per clip). With
    ``lead_s`` the clip has that much more before and after the phrase, and the noise
    (at the phrase's SNR) fills it too: the detector hears the noise before the phrase."""
    clips: list[tuple[str, np.ndarray]] = []
    lead = np.zeros(round(lead_s * SAMPLE_RATE_HZ), dtype=np.int16)
    for name, pcm in sources:
        for snr in SNRS_DB:
            rng = np.random.default_rng([WAKE_NOISE_SEED, len(clips)])
            if lead_s > 0 and snr is not None:
                sig = float(np.sqrt(np.mean(pcm.astype(np.float64) ** 2)))
                x = np.concatenate([lead, pcm, lead]).astype(np.float64)
                x += rng.normal(0.0, sig / 10 ** (snr / 20), len(x))
                clips.append((f"{name} {snr}dB lead", np.clip(x, -32768, 32767).astype(np.int16)))
            elif lead_s <= 0:
                clips.append((f"{name} {snr}dB", noisy(pcm, snr, rng)))
    return clips


def babble_clips(sources: list[tuple[str, np.ndarray]], talkers: list[np.ndarray]
                  ) -> list[tuple[str, np.ndarray]]:  # fmt: skip
    """Each source in the babble of ``BABBLE_TALKERS`` other talkers at ``BABBLE_SNRS_DB``."""
    clips: list[tuple[str, np.ndarray]] = []
    for name, pcm in sources:
        for snr in BABBLE_SNRS_DB:
            rng = np.random.default_rng([BABBLE_SEED, len(clips)])
            babble = np.zeros(len(pcm))
            for j in rng.choice(len(talkers), BABBLE_TALKERS, replace=False):
                src = np.tile(talkers[j].astype(np.float64), len(pcm) // len(talkers[j]) + 2)
                off = int(rng.integers(0, len(talkers[j])))
                babble += src[off : off + len(pcm)]
            sig = float(np.sqrt(np.mean(pcm.astype(np.float64) ** 2)))
            babble *= sig / 10 ** (snr / 20) / (float(np.sqrt(np.mean(babble**2))) + 1e-9)
            clips.append((f"{name} babble {snr}dB", np.clip(pcm + babble, -32768, 32767).astype(np.int16)))
    return clips


def babble_talkers(speech: Any) -> list[np.ndarray]:
    """Other talkers for the babble: neutral sentences in Piper's and espeak-ng's voices."""
    from sage_robot.voice.audio_io import resample
    from sage_robot.voice.tts import EspeakEngine

    piper = speech.engine
    out = [resample(piper.synthesize_sentence(s), piper.sample_rate, SAMPLE_RATE_HZ) for s in NEUTRAL[:6]]
    for voice in ESPEAK_VOICES:
        es = EspeakEngine(voice, ESPEAK_RATES[1])
        pcm = es.synthesize_sentence(NEUTRAL[6 + len(out) % 6])
        out.append(resample(pcm, es.sample_rate, SAMPLE_RATE_HZ))
    return out


def false_rejects(engine: Any, clips: list[tuple[str, np.ndarray]], vs: Any, model: str = "hey_jarvis",
                   prefix: str = "wake") -> dict[str, Any]:  # fmt: skip
    """Clips (1 s of silence either side) in which ``model`` is not detected."""
    from sage_robot.voice.wake import WakeDetector

    pad = np.zeros(SAMPLE_RATE_HZ, dtype=np.int16)
    missed = []
    for name, pcm in clips:
        engine.reset()
        det = WakeDetector.from_settings(engine, vs)
        if model not in {d.model for d in det.feed(np.concatenate([pad, pcm, pad]))}:
            missed.append(name)
    return {f"{prefix}_clips": len(clips), f"{prefix}_false_rejects": len(missed),
            f"{prefix}_false_reject_rate": round(len(missed) / max(1, len(clips)), 3),
            f"{prefix}_missed": missed[:10]}  # fmt: skip


def seeded(base: int, seed: int) -> np.random.Generator:
    """The bench's stream ``base``; ``seed`` 0 keeps the original stream, others vary it."""
    return np.random.default_rng(base if seed == 0 else [base, seed])


def non_wake_audio(speech: Any, minutes: float, seed: int = 0) -> np.ndarray:
    """Other speech (Piper, espeak-ng voices, real recordings) and noise, ``minutes`` long."""
    from sage_robot.voice.audio_io import load_audio, resample
    from sage_robot.voice.tts import EspeakEngine

    rng = seeded(5, seed)
    want = int(minutes * 60 * SAMPLE_RATE_HZ)
    parts: list[np.ndarray] = [load_audio(p) for p in sorted(POCKETSPHINX.glob("librivox/*.wav"))]
    piper = speech.engine
    for s in NEUTRAL:
        parts.append(resample(piper.synthesize_sentence(s), piper.sample_rate, SAMPLE_RATE_HZ))
    voices = [EspeakEngine(v, r) for v in ESPEAK_VOICES for r in ESPEAK_RATES]
    speech_parts = list(parts)
    k = 0
    while sum(len(p) for p in parts) < want * 0.8:
        es = voices[k % len(voices)]
        s = NEUTRAL[k % len(NEUTRAL)]
        parts.append(resample(es.synthesize_sentence(s), es.sample_rate, SAMPLE_RATE_HZ))
        speech_parts.append(parts[-1])
        k += 1
    while sum(len(p) for p in parts) < want:  # noise: white, brown, and babble of voices
        n = 5 * SAMPLE_RATE_HZ
        kind = len(parts) % 3
        if kind == 0:
            parts.append(rng.normal(0, 800, n).astype(np.int16))
        elif kind == 1:
            brown = np.cumsum(rng.normal(0, 60, n))
            parts.append(np.clip(brown - np.mean(brown), -20000, 20000).astype(np.int16))
        else:
            babble = np.zeros(n)
            for j in rng.choice(len(speech_parts), 3):
                src = speech_parts[j][:n]
                babble[: len(src)] += src * 0.4
            parts.append(np.clip(babble, -32768, 32767).astype(np.int16))
    gap = np.zeros(SAMPLE_RATE_HZ // 2, dtype=np.int16)
    return np.concatenate([x for p in parts for x in (p, gap)])[:want]


def false_accepts(engine: Any, audio: np.ndarray, vs: Any, profile_models: Any) -> dict[str, Any]:
    """Detections over non-wake audio: by the profile's models, and by ``alexa`` apart."""
    from sage_robot.voice.wake import WakeDetector

    engine.reset()
    det = WakeDetector.from_settings(engine, vs)
    found = det.feed(audio)
    return {"fa_audio_min": round(len(audio) / SAMPLE_RATE_HZ / 60, 2),
            "wake_false_accepts": sum(d.model in profile_models for d in found),
            "alexa_false_accepts": sum(d.model == "alexa" for d in found),
            "fa_max_scores": {k: round(v, 3) for k, v in det.max_scores.items()},
            "fa_max_smoothed": {k: round(v, 3) for k, v in det.max_smoothed.items()},
            "fa_max_head_gated": {k: round(v, 3) for k, v in det.max_head_gated.items()},
            "fa_detections": [(d.model, round(d.time_s, 1)) for d in found[:10]]}  # fmt: skip


REAL_NOISE_SNRS_DB = (10.0, 5.0)  # real recordings again, in white noise at these ratios


def real_speech_in_noise(engine: Any, vs: Any, seed: int = 0) -> dict[str, Any]:
    """Detections by the profile's models on every real recording of ``POCKETSPHINX`` in
    white noise (the heads learned from synthetic voices only: this is where they could go
    wrong), and the heads' best smoothed scores, with and without the gate open."""
    from sage_robot.voice.audio_io import load_audio
    from sage_robot.voice.wake import WakeDetector

    files = sorted(POCKETSPHINX.glob("**/*.wav")) + sorted(POCKETSPHINX.glob("*.raw"))
    if not files:
        return {"real_noisy_audio_s": 0.0, "real_noisy_note": f"no recordings in {POCKETSPHINX}"}
    gap = np.zeros(SAMPLE_RATE_HZ // 2, dtype=np.int16)
    speech = np.concatenate([x for f in files for x in (load_audio(f), gap)]).astype(np.float64)
    rng = seeded(13, seed)
    found, head_max, gated_max = 0, 0.0, 0.0
    for snr in REAL_NOISE_SNRS_DB:
        x = speech + rng.normal(0.0, float(np.sqrt(np.mean(speech**2))) / 10 ** (snr / 20), len(speech))
        engine.reset()
        det = WakeDetector.from_settings(engine, vs)
        found += sum(d.model in vs.wake_models for d in det.feed(np.clip(x, -32768, 32767).astype(np.int16)))
        heads = list(det.max_head_gated)
        head_max = max([head_max] + [det.max_smoothed[k] for k in heads])
        gated_max = max([gated_max] + [det.max_head_gated[k] for k in heads])
    return {"real_noisy_audio_s": round(len(speech) * len(REAL_NOISE_SNRS_DB) / SAMPLE_RATE_HZ, 1),
            "real_noisy_false_accepts": found, "real_noisy_head_max": round(head_max, 3),
            "real_noisy_head_max_gated": round(gated_max, 3)}  # fmt: skip


HEAD_MARGIN_MIN = 0.3  # the heads' best gated score on negatives stays this far under threshold


def head_margin(out: dict[str, Any], head_threshold: float) -> dict[str, Any]:
    """The heads' margin: their threshold minus their best smoothed score on any negative
    (the minutes of other speech and noise, real speech in noise) while the gate was open."""
    gated = [*out.get("fa_max_head_gated", {}).values()]
    if "real_noisy_head_max_gated" in out:
        gated.append(out["real_noisy_head_max_gated"])
    if not gated:
        return {}
    margin = head_threshold - max(gated)
    return {"wake_head_negatives_max_gated": round(max(gated), 3), "wake_head_margin": round(margin, 3),
            "wake_head_margin_ok": margin >= HEAD_MARGIN_MIN}  # fmt: skip
