"""Audio plumbing (resampling, files, browser uploads through real ffmpeg), text
normalisation for speech, and the TTS engines."""

from __future__ import annotations

import shutil
import subprocess

import numpy as np
import pytest

from sage_robot.core.errors import ConfigError
from sage_robot.voice.audio_io import (
    AudioError,
    Framer,
    decode_upload,
    load_audio,
    resample,
    wav_bytes,
    write_wav,
)
from sage_robot.voice.textnorm import normalize, split_sentences
from sage_robot.voice.tts import EspeakEngine, Speech, make_engine, mouth_envelope, synthesize


def tone(freq: float, rate: int, seconds: float = 1.0) -> np.ndarray:
    t = np.arange(int(rate * seconds)) / rate
    return (0.5 * np.sin(2 * np.pi * freq * t) * 32767).astype(np.int16)


def peak_hz(x: np.ndarray, rate: int) -> float:
    spec = np.abs(np.fft.rfft(x.astype(np.float64) * np.hanning(len(x))))
    return float(np.fft.rfftfreq(len(x), 1 / rate)[np.argmax(spec)])


def test_resample_keeps_pitch_length_and_removes_aliases():
    x = tone(440, 22050)
    y = resample(x, 22050, 16000)
    assert y.dtype == np.int16
    assert abs(len(y) - 16000) <= 1
    assert peak_hz(y, 16000) == pytest.approx(440, abs=2)
    # 9 kHz cannot exist at 16 kHz: a proper resampler filters it, it does not fold to 7 kHz.
    z = resample(tone(9000, 48000), 48000, 16000)
    assert np.sqrt(np.mean(z.astype(np.float64) ** 2)) < 200
    with pytest.raises(AudioError, match="positive"):
        resample(x, 0, 16000)


def test_framer_recuts_any_chunks():
    fr = Framer(1280)
    frames = fr.push(np.arange(1000, dtype=np.int16)) + fr.push(np.arange(2000, dtype=np.int16))
    assert [len(f) for f in frames] == [1280, 1280]
    assert frames[1][0] == 1280 - 1000 + 0  # continuity across pushes


@pytest.mark.skipif(shutil.which("ffmpeg") is None, reason="ffmpeg not installed (apt)")
def test_browser_upload_webm_opus_decodes_to_16k(tmp_path):
    wav = tmp_path / "in.wav"
    write_wav(wav, tone(440, 48000, 2.0), 48000)
    webm = tmp_path / "in.webm"
    subprocess.run(["ffmpeg", "-loglevel", "error", "-i", str(wav), "-c:a", "libopus", str(webm)],
                   check=True, timeout=60)  # fmt: skip
    pcm = decode_upload(webm.read_bytes())
    assert pcm.dtype == np.int16
    assert len(pcm) / 16000 == pytest.approx(2.0, abs=0.05)
    assert peak_hz(pcm, 16000) == pytest.approx(440, abs=3)
    with pytest.raises(AudioError, match="not audio ffmpeg can decode"):
        decode_upload(b"this is not audio at all")
    with pytest.raises(AudioError, match="empty"):
        decode_upload(b"")


def test_load_audio_formats(tmp_path):
    x = tone(300, 8000, 0.5)
    (tmp_path / "a.wav").write_bytes(wav_bytes(x, 8000))
    assert len(load_audio(tmp_path / "a.wav")) == 8000  # 0.5 s at 16 kHz
    (tmp_path / "b.raw").write_bytes(x.tobytes())
    assert np.array_equal(load_audio(tmp_path / "b.raw"), x)  # raw = 16 kHz int16 as is
    (tmp_path / "odd.raw").write_bytes(b"\x00\x01\x02")
    with pytest.raises(AudioError, match="odd byte count"):
        load_audio(tmp_path / "odd.raw")
    with pytest.raises(AudioError, match="no such audio file"):
        load_audio(tmp_path / "missing.wav")


@pytest.mark.parametrize(
    ("text", "spoken"),
    [
        ("The lab is 2.5 km away.", "The lab is two point five kilometers away."),
        ("See https://valpo.edu/engineering for **details**.", "See for details."),
        ("Dr. Smith is in room 101 at 3:30 pm.", "Doctor Smith is in room one hundred and one at three "
         "thirty p m."),
        ("It costs $4.50 & it's 20% off!", "It costs four dollars and fifty cents and it's twenty percent"
         " off!"),
        ("Founded in 1859, on the 1st floor.", "Founded in eighteen fifty-nine, on the first floor."),
        ("## Hours\n- Open 9:00 daily 😀", "Hours\nOpen nine o'clock daily"),
        ("Top speed: 0.8 m/s, 1 m wide.", "Top speed: zero point eight meters per second, one meter wide."),
        ("Read [the guide](http://x.y/z) e.g. `page 2`.", "Read the guide for example page two."),
        ("1,250 students", "one thousand two hundred and fifty students"),
    ],
)
def test_normalize_for_speech(text, spoken):
    assert normalize(text) == spoken


def test_normalize_leaves_no_symbols():
    out = normalize("**Wow** <b>#1</b> | ~x~ {y} [z] \\ ^ `code` www.example.com/a?b=c")
    assert not set(out) & set("*#<>|~{}[]\\^`/")
    assert "www" not in out


def test_split_sentences_for_streaming():
    assert split_sentences("Hello there. How are you? Fine!") == ["Hello there.", "How are you?", "Fine!"]
    long = "word, " * 80 + "end."
    parts = split_sentences(long)
    assert len(parts) > 1
    assert all(len(p) <= 301 for p in parts)


def test_piper_is_deterministic_and_streams_sentence_by_sentence(models):
    speech = models.speech
    a = speech.synthesize("The lab is on the first floor. Follow me.")
    b = speech.synthesize("The lab is on the first floor. Follow me.")
    assert np.array_equal(a, b)
    assert len(a) / speech.sample_rate > 1.5
    parts = list(speech.stream("The lab is on the first floor. Follow me."))
    assert len(parts) == 2
    assert sum(len(p) for p in parts) == len(a)


def test_mouth_envelope_follows_loudness(models):
    speech = models.speech
    pcm = np.concatenate([np.zeros(speech.sample_rate, np.int16), speech.synthesize("Hello.")])
    env = mouth_envelope(pcm, speech.sample_rate)
    blocks_per_s = round(1 / 0.04)
    assert env[:blocks_per_s].max() == 0.0
    assert env[blocks_per_s:].max() > 0.5
    assert ((env >= 0) & (env <= 1)).all()


@pytest.mark.skipif(shutil.which("espeak-ng") is None, reason="espeak-ng not installed (apt)")
def test_espeak_engine_is_a_drop_in_tts(models):
    speech = Speech(EspeakEngine())
    pcm = speech.synthesize("Go forward 10 meters.")
    assert speech.sample_rate == 22050
    assert len(pcm) > 0.8 * 22050
    text = models.stt.transcribe(resample(pcm, speech.sample_rate, 16000)).text.lower()
    assert "forward" in text
    assert "ten" in text or "10" in text


def test_engine_choice_errors_and_web_helper(models, monkeypatch):
    import sage_robot.voice.tts as tts

    monkeypatch.setattr(tts, "_default", models.speech)  # the shared voice, already loaded
    with pytest.raises(ConfigError, match="unknown TTS engine 'festival'"):
        make_engine("festival")
    with pytest.raises(ConfigError, match=r"Piper voice '/nope\.onnx'"):
        make_engine("piper", "/nope.onnx")
    pcm, rate = synthesize("Hello.")
    assert pcm.dtype == np.int16
    assert rate > 0
    assert len(pcm) > 0.2 * rate
