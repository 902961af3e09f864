"""Voice: STT and TTS speed, reply latency with an echo brain, wake-word errors, CPU per frame.

- STT real-time factor on real recordings (Debian's pocketsphinx-testdata) or Piper speech.
- TTS real-time factor and time to the first sentence's audio.
- End of speech → first audio: whole turns through the pipeline on the wall clock, with a
  brain that echoes the question (the simulated room's mic and speaker).
- Wake false rejects over synthesized "hey jarvis" (Piper at several speeds, espeak-ng
  voices, clean and in white noise; apart, in white noise that starts 2 s before the
  phrase, and in the babble of other talkers) and "alexa",
  and false accepts over minutes of other speech and noise.
- CPU per 80 ms frame (wake models + VAD).
- The wake heads' margin: their threshold minus their best score on every negative while
  the gate was open (kept >= 0.3; ``--seed N`` varies Piper's prosody and the noise,
  ``--wake-only`` runs this part alone).
"""

from __future__ import annotations

import argparse
import asyncio
import statistics
import time
from typing import Any

import numpy as np

from sage_robot.bench.voice_wake import (
    ALEXA_PHRASES,
    POCKETSPHINX,
    WAKE_LEAD_S,
    WAKE_MODELS,
    WAKE_PHRASES,
    babble_clips,
    babble_talkers,
    false_accepts,
    false_rejects,
    head_margin,
    non_wake_audio,
    real_speech_in_noise,
    wake_sources,
    white_clips,
)
from sage_robot.core.audio import FRAME_SAMPLES, SAMPLE_RATE_HZ

PARTIAL_ROUNDS = 5  # final transcriptions alone / with a partial running
LONG_QUESTIONS = ("Can you tell me where the robotics lab is and whether students work there today?",
                  "When does the library open on Saturday, and can I bring my friends along?",
                  "Where is the cafe that sells the good sandwiches near the engineering building?")
QUESTIONS = ("Where is the library?", "What time does the lab open?", "Who teaches robotics?",
             "Can you take me to the cafe?", "How old is this building?")  # fmt: skip
def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--turns", type=int, default=6, help="pipeline turns for the reply latency")
    p.add_argument("--ab-turns", type=int, default=8,
                   help="long-question turns, partial transcripts on/off in turn (0: skip)")
    p.add_argument("--fa-minutes", type=float, default=10.0, help="minutes of non-wake audio")
    p.add_argument("--quick", action="store_true", help="small sizes (a smoke test)")
    p.add_argument("--seed", type=int, default=0,
                   help="seeds Piper's prosody noise and the noise of the wake sets (0: the original noise)")
    p.add_argument("--wake-only", action="store_true", help="only the wake-word part (no STT, TTS, turns)")


def _stt(stt: Any, speech: Any) -> dict[str, Any]:
    from sage_robot.voice.audio_io import load_audio, resample

    clips = [*sorted(POCKETSPHINX.glob("librivox/*.wav"))[:3], POCKETSPHINX / "goforward.raw"]
    audio = [load_audio(c) for c in clips if c.is_file()]
    if not audio:  # no test data installed: Piper speech instead
        audio = [resample(speech.synthesize(q), speech.sample_rate, SAMPLE_RATE_HZ) for q in QUESTIONS[:3]]
    rtf = []
    for pcm in audio:
        r = stt.transcribe(pcm)
        rtf.append(r.elapsed_s / r.duration_s)
    return {"stt_rtf_median": round(statistics.median(rtf), 3), "stt_clips": len(rtf),
            "stt_audio_s": round(sum(len(a) for a in audio) / SAMPLE_RATE_HZ, 1)}  # fmt: skip


def _tts(speech: Any) -> dict[str, Any]:
    text = "Welcome to the engineering building. The robotics lab is on the first floor, " \
           "past the glass doors. Please follow me and mind the step."  # fmt: skip
    firsts, rtfs = [], []
    for _ in range(3):
        t0 = time.perf_counter()
        total = 0
        for i, pcm in enumerate(speech.stream(text)):
            if i == 0:
                firsts.append(time.perf_counter() - t0)
            total += len(pcm)
        rtfs.append((time.perf_counter() - t0) / (total / speech.sample_rate))
    return {"tts_rtf_median": round(statistics.median(rtfs), 3),
            "tts_first_audio_s_median": round(statistics.median(firsts), 3)}  # fmt: skip


def _frame_cpu(models: Any, settings: Any) -> dict[str, Any]:
    """The profile's wake detector (both paths with ``wake_denoise``) and the VAD."""
    from sage_robot.voice.wake import WakeDetector

    rng = np.random.default_rng(3)
    x = rng.normal(0, 300, FRAME_SAMPLES * 200).astype(np.int16)
    models.wake.reset()
    det = WakeDetector.from_settings(models.wake, settings)
    models.vad.reset()
    c0, t0 = time.process_time(), time.perf_counter()
    for i in range(200):
        frame = x[i * FRAME_SAMPLES : (i + 1) * FRAME_SAMPLES]
        det.feed_frame(frame)
        models.vad.frame_probability(frame)
    cpu_ms = (time.process_time() - c0) / 200 * 1000
    wall_ms = (time.perf_counter() - t0) / 200 * 1000
    return {"cpu_ms_per_80ms_frame": round(cpu_ms, 2), "wall_ms_per_80ms_frame": round(wall_ms, 2),
            "cpu_share_of_realtime": round(cpu_ms / 80, 3)}  # fmt: skip


async def _turns(models: Any, settings: Any, speech: Any, questions: tuple[str, ...], turns: int,
                 partial_on: Any = None) -> list[tuple[Any, int, bool]]:  # fmt: skip
    """Whole turns through the pipeline on the wall clock: (TurnLatency, partials shown, partials
    on) per turn. ``partial_on(i)`` switches partial transcripts per turn (an A/B under the
    same machine load); None keeps the profile's choice."""
    from sage_robot.core.bus import Bus
    from sage_robot.core.clock import WallClock
    from sage_robot.core.msgs import Text
    from sage_robot.core.topics import CONVERSE
    from sage_robot.sim.audio import SimMicrophone, SimSpeaker
    from sage_robot.voice.audio_io import resample
    from sage_robot.voice.node import build_pipeline
    from sage_robot.voice.pipeline import State

    clock = WallClock()
    bus = Bus(clock)

    async def echo(goal: Text, ctx: Any) -> Text:
        ctx.feedback(Text(f"You asked: {goal.data}"))
        return Text(goal.data)

    bus.actions.serve(CONVERSE, echo)
    mic = SimMicrophone(clock)
    spk = SimSpeaker(clock, mic, echo_gain=0.1)
    pipe = build_pipeline(bus, clock, settings, models, mic, spk)
    task = asyncio.create_task(pipe.run())

    def say(text: str) -> np.ndarray:
        return resample(speech.synthesize(text), speech.sample_rate, SAMPLE_RATE_HZ)

    pause = np.zeros(SAMPLE_RATE_HZ // 2, dtype=np.int16)
    out = []
    for i in range(turns):
        if partial_on is not None:
            pipe.partial_stt = models.stt_partial if partial_on(i) else None
        mic.inject(np.concatenate([pause, say("Hey Jarvis."), pause,
                                   say(questions[i % len(questions)]), pause]))  # fmt: skip
        deadline = time.monotonic() + 60
        n, shown = len(pipe.latencies), pipe.partials
        while time.monotonic() < deadline and (len(pipe.latencies) == n or pipe.state is not State.IDLE
                                               or mic.pending_s > 0):  # fmt: skip
            await asyncio.sleep(0.05)
        if len(pipe.latencies) > n:
            out.append((pipe.latencies[-1], pipe.partials - shown, pipe.partial_stt is not None))
    task.cancel()
    await asyncio.gather(task, return_exceptions=True)
    return out


def _delays(turns: list[tuple[Any, int, bool]]) -> list[float]:
    return [m.reply_delay_s for m, _, _ in turns if m.reply_delay_s == m.reply_delay_s]


async def _latency(models: Any, settings: Any, speech: Any, turns: int) -> dict[str, Any]:
    done = await _turns(models, settings, speech, QUESTIONS, turns)
    delays = _delays(done)
    stt = [m.stt_done - m.end_of_speech for m, _, _ in done if m.stt_done == m.stt_done]
    out: dict[str, Any] = {"turns": len(done), "turns_answered": len(delays)}
    if delays:
        out["end_of_speech_to_first_audio_s_median"] = round(statistics.median(delays), 3)
        out["end_of_speech_to_first_audio_s_max"] = round(max(delays), 3)
        out["last_word_to_first_audio_s_median"] = round(
            statistics.median(delays) + settings.vad_silence_s, 3)  # fmt: skip
    if stt:
        out["stt_s_median"] = round(statistics.median(stt), 3)
    return out


def _partial_contention(models: Any, rounds: int) -> dict[str, Any]:
    """The final transcription of ``goforward.raw`` alone and with a partial transcript
    running at the same time (started 50 ms before), alternately: what a partial costs the
    reply, with little of the load noise of whole turns."""
    import threading

    from sage_robot.voice.audio_io import load_audio

    clip = POCKETSPHINX / "goforward.raw"
    if models.stt_partial is None or not clip.is_file() or rounds <= 0:
        return {}
    pcm = load_audio(clip)
    alone, shared = [], []
    for _ in range(rounds):
        t0 = time.perf_counter()
        models.stt.transcribe(pcm, True)
        alone.append(time.perf_counter() - t0)
        th = threading.Thread(target=models.stt_partial.transcribe, args=(pcm, True))
        th.start()
        time.sleep(0.05)
        t0 = time.perf_counter()
        models.stt.transcribe(pcm, True)
        shared.append(time.perf_counter() - t0)
        th.join()
    return {"final_stt_s_median_alone": round(statistics.median(alone), 3),
            "final_stt_s_median_with_partial": round(statistics.median(shared), 3)}  # fmt: skip


async def _partial_ab(models: Any, settings: Any, speech: Any, turns: int) -> dict[str, Any]:
    """Long questions (4-6 s), partial transcripts on in even turns and off in odd ones."""
    if models.stt_partial is None:
        return {}
    done = await _turns(models, settings, speech, LONG_QUESTIONS, turns, lambda i: i % 2 == 0)
    on = _delays([t for t in done if t[2]])
    off = _delays([t for t in done if not t[2]])
    out: dict[str, Any] = {"long_turns": len(done),
                           "long_partials_per_turn": round(sum(t[1] for t in done if t[2])
                                                           / max(1, len(on)), 1)}  # fmt: skip
    if on and off:
        out["long_reply_delay_s_median_partials_on"] = round(statistics.median(on), 3)
        out["long_reply_delay_s_median_partials_off"] = round(statistics.median(off), 3)
    return out


def run(args: argparse.Namespace) -> dict[str, Any]:
    import os

    import onnxruntime

    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    from sage_robot.core.config.areas import VoiceSettings
    from sage_robot.voice.node import VoiceModels
    from sage_robot.voice.tts import Speech, make_engine

    onnxruntime.set_seed(args.seed)  # before Piper's session: its prosody noise is seeded (0 too)
    settings = VoiceSettings(tts_deterministic=False)
    out: dict[str, Any] = {"bench": "voice", "seed": args.seed, "cpus": os.cpu_count(),
                           "load_avg_1min": round(os.getloadavg()[0], 1)}  # fmt: skip
    if args.wake_only:
        out.update(_wake(Speech(make_engine("piper", settings.tts_voice)), settings, args))
        return out
    t0 = time.perf_counter()
    models = VoiceModels.load(settings)
    out["load_s"] = round(time.perf_counter() - t0, 2)
    out.update(_frame_cpu(models, settings))
    out.update(_stt(models.stt, models.speech))
    out.update(_tts(models.speech))
    out.update(asyncio.run(_latency(models, settings, models.speech, 2 if args.quick else args.turns)))
    out["asr_partial"] = settings.asr_partial
    out.update(_partial_contention(models, 2 if args.quick else PARTIAL_ROUNDS))
    out.update(asyncio.run(_partial_ab(models, settings, models.speech, 2 if args.quick else args.ab_turns)))
    out.update(_wake(models.speech, settings, args))
    return out


def _wake(speech: Any, settings: Any, args: argparse.Namespace) -> dict[str, Any]:
    """False rejects, false accepts and the heads' margin (see module doc)."""
    from sage_robot.voice.wake import OpenWakeWordEngine

    # The profile's hey_jarvis and the opt-in alexa, scored together (models are independent).
    both = settings.model_copy(update={"wake_models": WAKE_MODELS})
    engine = OpenWakeWordEngine(WAKE_MODELS)
    out: dict[str, Any] = {"wake_models": list(settings.wake_models)}
    out["wake_thresholds"] = {n: both.wake_model_thresholds.get(n, both.wake_threshold)
                              for n in WAKE_MODELS}  # fmt: skip
    out["wake_patience"] = {n: both.wake_model_patience.get(n, both.wake_patience_frames)
                            for n in WAKE_MODELS}  # fmt: skip
    out["wake_smoothing"] = {n: both.wake_model_smoothing.get(n, both.wake_smoothing_frames)
                             for n in WAKE_MODELS}  # fmt: skip
    out["wake_denoise"] = settings.wake_denoise
    out["wake_denoise_thresholds"] = dict(settings.wake_denoise_thresholds)
    out["wake_heads"] = dict(settings.wake_heads)
    out["wake_head_threshold"], out["wake_head_gate"] = settings.wake_head_threshold, settings.wake_head_gate
    jarvis = wake_sources(speech, WAKE_PHRASES, args.quick)
    out.update(false_rejects(engine, white_clips(jarvis), both))
    no_head = both.model_copy(update={"wake_heads": {}})  # A/B: the same clips without the heads
    out.update(false_rejects(engine, white_clips(jarvis), no_head, prefix="wake_no_head"))
    out.update(false_rejects(engine, white_clips(jarvis, WAKE_LEAD_S), both, prefix="wake_lead"))
    talkers = babble_talkers(speech)
    out.update(false_rejects(engine, babble_clips(jarvis, talkers), both, prefix="wake_babble"))
    alexa = wake_sources(speech, ALEXA_PHRASES, args.quick)
    out.update(false_rejects(engine, white_clips(alexa), both, "alexa", prefix="alexa"))
    minutes = 0.5 if args.quick else args.fa_minutes
    out.update(false_accepts(engine, non_wake_audio(speech, minutes, args.seed), both,
                              settings.wake_models))  # fmt: skip
    out.update(real_speech_in_noise(engine, settings, args.seed))
    out.update(head_margin(out, settings.wake_head_threshold))
    return out
