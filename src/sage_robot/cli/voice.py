"""`sage voice ...`: transcribe a file, find wake words in it, speak text, listen live."""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
import time
from typing import Any


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser("voice", help="speech to text, wake words, text to speech, live listening")
    p.set_defaults(help_parser=p)
    vsub = p.add_subparsers(dest="voice_command", metavar="COMMAND")

    t = vsub.add_parser("transcribe", help="transcribe an audio file (WAV, raw 16 kHz, WebM, MP3...)")
    t.add_argument("file")
    t.add_argument("--model", help="Whisper model: tiny.en (bundled) or a model directory")
    t.add_argument("--device", choices=["cpu", "cuda"], help="where the model runs")
    t.add_argument("--json", action="store_true", help="print text, confidence, segments as JSON")
    t.set_defaults(func=cmd_transcribe)

    w = vsub.add_parser("wake", help="find wake words in an audio file, or calibrate a model",
                        description="sage voice wake FILE: find wake words in it. "
                        "sage voice wake calibrate --model M --positives DIR --negatives DIR: pick "
                        "M's threshold and patience from recordings (written to --profile FILE)."
                        )  # fmt: skip
    w.add_argument("file", help="an audio file, or 'calibrate'")
    w.add_argument("--model", action="append", help="bundled name or .onnx path (repeatable)")
    w.add_argument("--threshold", type=float, help="score threshold (default: the profile's)")
    w.add_argument("--json", action="store_true", help="print the result as JSON")
    w.add_argument("--positives", help="calibrate: folder of wake-phrase clips")
    w.add_argument("--negatives", help="calibrate: folder of recordings without the wake phrase")
    w.add_argument("--max-fa-per-hour", type=float, default=None,
                   help="calibrate: false accepts per hour of negatives allowed (default 1)")  # fmt: skip
    w.add_argument("--dry-run", action="store_true", help="calibrate: do not write the profile")
    w.set_defaults(func=cmd_wake)

    s = vsub.add_parser("say", help="speak text on the speaker, or write it to a WAV file")
    s.add_argument("text")
    s.add_argument("--out", help="write a WAV file instead of playing")
    s.add_argument("--engine", choices=["piper", "espeak"], help="TTS engine (default: profile)")
    s.set_defaults(func=cmd_say)

    li = vsub.add_parser("listen", help="live from the microphone: print wake words and what is said")
    li.add_argument("--seconds", type=float, help="stop after this long (default: Ctrl-C)")
    li.set_defaults(func=cmd_listen)


def _settings(args: argparse.Namespace) -> Any:
    from sage_robot.core.config import load_profile

    return load_profile(args.profile).voice


def cmd_transcribe(args: argparse.Namespace) -> int:
    from sage_robot.voice.audio_io import load_audio
    from sage_robot.voice.stt import SpeechToText

    vs = _settings(args)
    pcm = load_audio(args.file)
    stt = SpeechToText(args.model or vs.stt_model, args.device or vs.stt_device, vs.stt_compute_type)
    result = stt.transcribe(pcm)
    if args.json:
        print(json.dumps({"file": args.file, **result.as_dict()}))
    else:
        print(result.text if result.text else "(unclear: nothing trustworthy was heard)"
              if result.unclear else "(no speech)")  # fmt: skip
    return 0


def cmd_wake(args: argparse.Namespace) -> int:
    from sage_robot.core.audio import SAMPLE_RATE_HZ
    from sage_robot.core.errors import ConfigError

    if args.file == "calibrate":
        from sage_robot.cli.voice_calibrate import cmd_calibrate

        return cmd_calibrate(args)
    if args.positives or args.negatives or args.max_fa_per_hour is not None:
        raise ConfigError("--positives, --negatives and --max-fa-per-hour are for "
                          "'sage voice wake calibrate'")  # fmt: skip
    from sage_robot.voice.audio_io import load_audio
    from sage_robot.voice.wake import OpenWakeWordEngine, WakeDetector

    vs = _settings(args)
    threshold = vs.wake_threshold if args.threshold is None else args.threshold  # reported
    if not 0 <= threshold <= 1:
        raise ConfigError(f"--threshold must be between 0 and 1, got {threshold}")
    pcm = load_audio(args.file)
    engine = OpenWakeWordEngine(args.model or vs.wake_models)
    detector = WakeDetector.from_settings(engine, vs, args.threshold)
    found = detector.feed(pcm)
    out = {
        "file": args.file,
        "threshold": threshold,
        "thresholds": detector.thresholds,
        "patience": detector.patiences,
        "duration_s": round(len(pcm) / SAMPLE_RATE_HZ, 3),
        "detections": [
            {"model": d.model, "time_s": round(d.time_s, 2), "score": round(d.score, 4)} for d in found
        ],
        "max_scores": {k: round(v, 4) for k, v in detector.max_scores.items()},
    }
    if detector.heads:  # scores under "<model>/head"; the threshold override is for models only
        out["heads"] = {m: h.name for m, h in detector.heads.items()}
        out["head_threshold"], out["head_gate"] = detector.head_threshold_value, detector.head_gate
    if args.json:
        print(json.dumps(out))
    else:
        for d in out["detections"]:
            print(f"{d['time_s']:7.2f} s  {d['model']}  {d['score']:.3f}")
        print("max: " + ", ".join(f"{k} {v:.3f}" for k, v in out["max_scores"].items()))
    return 0


def cmd_say(args: argparse.Namespace) -> int:
    from sage_robot.voice.audio_io import write_wav
    from sage_robot.voice.tts import Speech, make_engine

    vs = _settings(args)
    if not args.text.strip():
        from sage_robot.core.errors import ConfigError

        raise ConfigError("nothing to say: the text is empty")
    speech = Speech(make_engine(args.engine or vs.tts_engine, vs.tts_voice, vs.tts_deterministic))
    t0 = time.perf_counter()
    pcm = speech.synthesize(args.text)
    took = time.perf_counter() - t0
    seconds = len(pcm) / speech.sample_rate
    if args.out:
        write_wav(args.out, pcm, speech.sample_rate)
        print(f"wrote {args.out}: {seconds:.2f} s at {speech.sample_rate} Hz (made in {took:.2f} s)")
        return 0
    from sage_robot.hardware.audio import SoundDeviceSpeaker

    speaker = SoundDeviceSpeaker(vs.speaker_device)
    try:
        asyncio.run(speaker.play(pcm, speech.sample_rate))
    finally:
        speaker.close()
    return 0


def cmd_listen(args: argparse.Namespace) -> int:
    return asyncio.run(_listen(_settings(args), args.seconds))


async def _listen(vs: Any, seconds: float | None) -> int:
    from sage_robot.hardware.audio import SoundDeviceMicrophone
    from sage_robot.voice.stt import SpeechToText
    from sage_robot.voice.vad import EndReason, SileroVad, UtteranceRecorder
    from sage_robot.voice.wake import OpenWakeWordEngine, WakeDetector

    mic = SoundDeviceMicrophone(vs.mic_device, vs.mic_channel)
    print("loading models...", file=sys.stderr)
    wake = WakeDetector.from_settings(OpenWakeWordEngine(vs.wake_models), vs)
    vad, stt = SileroVad(), SpeechToText(vs.stt_model, vs.stt_device, vs.stt_compute_type)
    rec = UtteranceRecorder(vs.vad_threshold, vs.vad_silence_s, vs.vad_preroll_s, vs.max_utterance_s,
                            start_timeout_s=float("inf"))  # fmt: skip
    print("listening (Ctrl-C to stop)", file=sys.stderr)
    end = None if seconds is None else time.monotonic() + seconds
    try:
        while end is None or time.monotonic() < end:
            frame = await mic.read()
            for d in await asyncio.to_thread(wake.feed, frame):
                print(f"[wake] {d.model} {d.score:.2f}", flush=True)
            utt = rec.push(frame, await asyncio.to_thread(vad.frame_probability, frame))
            if utt is not None and utt.reason is not EndReason.NO_SPEECH:
                heard = await asyncio.to_thread(stt.transcribe, utt.pcm)
                if heard.unclear or (heard.text and heard.confidence < vs.stt_min_confidence):
                    print("(did not catch that)", flush=True)
                elif heard.text:
                    print(heard.text, flush=True)
    finally:
        mic.close()
    return 0
