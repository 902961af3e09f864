"""Speech to text on real recordings, VAD end-of-utterance, and the Piper → resample →
wake → VAD → STT round trip."""

from __future__ import annotations

import re

import numpy as np
import pytest

from sage_robot.core.audio import FRAME_S, FRAME_SAMPLES
from sage_robot.core.errors import ConfigError
from sage_robot.voice.audio_io import Framer, load_audio, resample
from sage_robot.voice.stt import NO_SPEECH, SpeechToText, Transcript, transcribe_pcm
from sage_robot.voice.vad import EndReason, SileroVad, Utterance, UtteranceRecorder
from sage_robot.voice.wake import WakeDetector

from .conftest import noise, silence

NUMBER_WORDS = {"10": "ten", "4": "four", "5": "five", "7": "seven", "8": "eight"}


def words(text: str) -> list[str]:
    out = []
    for w in re.findall(r"[a-z0-9']+", text.lower()):
        out.append(NUMBER_WORDS.get(w, w))
    return out


def word_errors(ref: str, hyp: str) -> int:
    """Levenshtein distance over words."""
    r, h = words(ref), words(hyp)
    d = list(range(len(h) + 1))
    for i in range(1, len(r) + 1):
        prev, d[0] = d[0], i
        for j in range(1, len(h) + 1):
            prev, d[j] = d[j], min(d[j] + 1, d[j - 1] + 1, prev + (r[i - 1] != h[j - 1]))
    return d[len(h)]


def test_goforward_recording(models, pocketsphinx_data):
    result = models.stt.transcribe(load_audio(pocketsphinx_data / "goforward.raw"))
    assert words(result.text) == ["go", "forward", "ten", "meters"]
    assert 0.3 < result.confidence <= 1
    assert result.no_speech_prob < 0.5
    assert result.duration_s == pytest.approx(2.786, abs=0.01)


def test_librivox_recordings_word_error_rate(models, pocketsphinx_data):
    """Real read speech (LibriVox, 16 kHz WAV) with the reference transcriptions."""
    refs = {}
    for line in (pocketsphinx_data / "librivox" / "transcription").read_text().splitlines():
        m = re.match(r"<s> (.*) </s> \((.*)\)", line.strip())
        if m:
            refs[m.group(2)] = m.group(1)
    errors = total = 0
    for name in ("sense_and_sensibility_01_austen_64kb-0880", "sense_and_sensibility_01_austen_64kb-0930"):
        hyp = models.stt.transcribe(load_audio(pocketsphinx_data / "librivox" / f"{name}.wav")).text
        errors += word_errors(refs[name], hyp)
        total += len(words(refs[name]))
    assert errors / total <= 0.15, f"WER {errors}/{total}"


@pytest.mark.parametrize(
    "clip",
    [silence(3.0), noise(3.0, rms=30), noise(3.0, rms=3000, seed=2), np.zeros(0, np.int16)],
    ids=["silence", "room-noise", "loud-noise", "empty"],
)
def test_silence_and_noise_give_no_words(models, clip):
    result = models.stt.transcribe(clip)
    assert result == Transcript("", duration_s=len(clip) / 16000, elapsed_s=result.elapsed_s,
                                rejected=NO_SPEECH)  # fmt: skip
    assert result.empty
    assert not result.unclear
    assert result.no_speech_prob == 1.0


@pytest.mark.parametrize("clip", [silence(3.0), noise(3.0, rms=3000, seed=2)], ids=["silence", "noise"])
def test_no_words_even_when_the_caller_says_it_is_speech(models, clip):
    """``speech_checked`` skips the Silero check only: Whisper's VAD filter and the
    no-speech / log-probability filters still turn silence and noise into no words."""
    assert models.stt.transcribe(clip, speech_checked=True).text == ""


def test_transcribe_pcm_helper_and_bad_input():
    with pytest.raises(Exception, match="mono"):
        transcribe_pcm(np.zeros((10, 2), np.int16))
    with pytest.raises(ConfigError, match="directory with a CTranslate2 Whisper model"):
        SpeechToText("/nonexistent/small.en")


def test_vad_scores_speech_high_and_silence_low(models, say16k):
    vad = SileroVad()
    speech = say16k("The robotics lab is on the first floor.")
    assert vad.speech_seconds(speech, 0.5) > 1.0
    assert vad.speech_seconds(noise(2.0), 0.5) == 0.0


def run_recorder(audio: np.ndarray, vad: SileroVad, **kw) -> tuple[UtteranceRecorder, Utterance | None, int]:
    rec = UtteranceRecorder(**kw)
    vad.reset()
    for n, frame in enumerate(Framer(FRAME_SAMPLES).push(audio)):
        utt = rec.push(frame, vad.frame_probability(frame))
        if utt is not None:
            return rec, utt, n
    return rec, None, -1


def test_utterance_ends_after_silence_and_keeps_the_preroll(models, say16k):
    speech = say16k("Where is the library?")
    audio = np.concatenate([silence(1.0), speech, silence(2.0)])
    _, utt, n = run_recorder(audio, models.vad, silence_s=0.7, preroll_s=0.4, start_timeout_s=5)
    assert utt is not None
    assert utt.reason is EndReason.SILENCE
    end_of_speech_s = (16000 + len(speech)) / 16000
    assert end_of_speech_s + 0.5 <= (n + 1) * FRAME_S <= end_of_speech_s + 1.0
    # The first syllable is inside: the utterance starts before the speech does.
    onset = int(np.argmax(np.abs(speech) > 500))
    start_in_audio = 16000 + onset
    utt_start = (n + 1) * FRAME_SAMPLES - len(utt.pcm)
    assert utt_start <= start_in_audio - 0.2 * 16000
    assert words(models.stt.transcribe(utt.pcm).text)[-2:] == ["the", "library"]


def test_max_length_and_no_speech(models, say16k):
    long = np.concatenate([say16k("Please follow me and mind the step.")] * 3)
    _, utt, _ = run_recorder(np.concatenate([silence(0.3), long]), models.vad, max_s=2.0)
    assert utt is not None
    assert utt.reason is EndReason.MAX_LENGTH
    assert len(utt.pcm) / 16000 <= 2.0 + FRAME_S
    _, utt, n = run_recorder(noise(3.0), models.vad, start_timeout_s=1.2)
    assert utt is not None
    assert utt.reason is EndReason.NO_SPEECH
    assert len(utt.pcm) == 0
    assert (n + 1) * FRAME_S == pytest.approx(1.2, abs=FRAME_S)


def test_round_trip_piper_resample_wake_vad_stt(models, say16k):
    """Piper (22.05 kHz) → soxr to 16 kHz → wake word → VAD utterance → Whisper."""
    speech = models.speech

    def tts16k(text):  # the full chain, not the cached helper
        return resample(speech.synthesize(text), speech.sample_rate, 16000)

    audio = np.concatenate([silence(0.5), tts16k("Hey Jarvis."), silence(0.3),
                            tts16k("Take me to the library, please."), silence(1.5)])  # fmt: skip
    models.wake.reset()
    wake = WakeDetector(models.wake)
    rec = UtteranceRecorder(silence_s=0.7, preroll_s=0.3)
    models.vad.reset()
    woke, utt = False, None
    for frame in Framer(FRAME_SAMPLES).push(audio):
        woke = woke or bool(wake.feed(frame))
        if woke and utt is None:
            utt = rec.push(frame, models.vad.frame_probability(frame))
    assert woke
    assert utt is not None
    assert utt.reason is EndReason.SILENCE
    text = models.stt.transcribe(utt.pcm).text
    assert {"take", "me", "library"} <= set(words(text)), text
    assert "jarvis" not in words(text)
