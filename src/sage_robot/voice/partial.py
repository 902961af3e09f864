"""Partial transcripts for the face, in a low-priority child process.

While the visitor speaks, the pipeline re-transcribes the utterance so far about once a
second (``asr_partial``). Whisper is not a streaming model: every call costs a fixed
~0.6 s of CPU here (faster-whisper pads each clip to a 30 s window), so on a 2-core machine
a partial that is still running when the visitor stops would slow the final transcription,
which decides how soon the robot answers. The partials therefore run in their own process
(``python -m sage_robot.voice.partial``: its own ``tiny.en`` on one thread) at a lower CPU
priority (``nice`` +10): the scheduler gives the final transcription and the audio loop the
CPU first, and a partial only uses what is left. Partials are for show; a late one is
dropped by the pipeline.

Protocol over the child's stdin/stdout: the child first writes one JSON line (``{"pid": N}``
or ``{"error": "..."}``); then per request the parent writes a JSON line
``{"samples": N, "speech_checked": bool}`` followed by N int16 samples (little-endian), and
the child answers one JSON line with the transcript's fields. End of stdin ends the child.
"""

from __future__ import annotations

import contextlib
import json
import os
import subprocess
import sys
import threading
from typing import IO, Any

import numpy as np

from sage_robot.core.errors import ConfigError, SageError
from sage_robot.voice.stt import SpeechToText, Transcript

PARTIAL_NICE = 10  # added niceness of the partial process (Linux CFS: ~1/10 the CPU share)
PARTIAL_THREADS = 1  # CPU threads of the partial model
CLOSE_TIMEOUT_S = 5.0  # wait this long for the child to exit before killing it


class PartialTranscriber:
    """``transcribe`` like :class:`SpeechToText`, run in a low-priority child process.

    Loading raises ``ConfigError`` with the child's message (e.g. an unknown model).
    ``transcribe`` blocks (call it from a worker thread) and is thread-safe.
    """

    def __init__(self, model: str = "tiny.en", nice: int = PARTIAL_NICE,
                 threads: int = PARTIAL_THREADS) -> None:  # fmt: skip
        cmd = [sys.executable, "-m", "sage_robot.voice.partial", model, str(threads), str(nice)]
        env = {**os.environ, "HF_HUB_OFFLINE": "1"}
        self._proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, env=env)
        self._lock = threading.Lock()
        hello = self._read()
        if "error" in hello:
            self.close()
            raise ConfigError(f"partial transcripts: {hello['error']}")
        self.pid = int(hello["pid"])
        self.name = model

    def _read(self) -> dict[str, Any]:
        assert self._proc.stdout is not None
        line = self._proc.stdout.readline()
        if not line:
            raise SageError("the partial-transcript process ended (see its error output)")
        return dict(json.loads(line))

    def transcribe(self, pcm16k: np.ndarray, speech_checked: bool = False) -> Transcript:
        pcm = np.ascontiguousarray(np.clip(np.asarray(pcm16k), -32768, 32767), dtype="<i2")
        if pcm.ndim != 1:
            raise ValueError(f"expected mono audio (1-D samples), got shape {pcm.shape}")
        head = json.dumps({"samples": len(pcm), "speech_checked": speech_checked}) + "\n"
        with self._lock:
            stdin = self._proc.stdin
            assert stdin is not None
            try:
                stdin.write(head.encode() + pcm.tobytes())
                stdin.flush()
            except (BrokenPipeError, ValueError):
                raise SageError("the partial-transcript process is not running") from None
            reply = self._read()
        if "error" in reply:
            raise SageError(f"partial transcript failed: {reply['error']}")
        return Transcript(reply["text"], reply["confidence"], reply["no_speech_prob"],
                          reply["duration_s"], reply["elapsed_s"])  # fmt: skip

    def close(self) -> None:
        """End the child (idempotent)."""
        if self._proc.stdin is not None and not self._proc.stdin.closed:
            with contextlib.suppress(OSError):
                self._proc.stdin.close()
        try:
            self._proc.wait(CLOSE_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait()
        if self._proc.stdout is not None:
            self._proc.stdout.close()


def _serve(model: str, threads: int, nice: int, inp: IO[bytes], out: IO[bytes]) -> None:
    def send(obj: dict[str, Any]) -> None:
        out.write(json.dumps(obj).encode() + b"\n")
        out.flush()

    with contextlib.suppress(OSError):  # not permitted: run at normal priority
        os.nice(nice)
    try:
        stt = SpeechToText(model, "cpu", "int8", cpu_threads=threads)
        stt.warm_up()
    except SageError as exc:
        send({"error": str(exc)})
        return
    send({"pid": os.getpid()})
    while True:
        line = inp.readline()
        if not line:
            return  # the parent closed stdin (or died)
        req = json.loads(line)
        data = inp.read(2 * int(req["samples"]))
        pcm = np.frombuffer(data, dtype="<i2").astype(np.int16)
        try:
            t = stt.transcribe(pcm, bool(req["speech_checked"]))
        except Exception as exc:  # one bad request does not end the process
            send({"error": str(exc)})
            continue
        send({"text": t.text, "confidence": t.confidence, "no_speech_prob": t.no_speech_prob,
              "duration_s": t.duration_s, "elapsed_s": t.elapsed_s})  # fmt: skip


def main(argv: list[str]) -> None:
    """``python -m sage_robot.voice.partial MODEL THREADS NICE`` (started by the parent)."""
    protocol = os.fdopen(os.dup(sys.stdout.fileno()), "wb")
    os.dup2(sys.stderr.fileno(), sys.stdout.fileno())  # stray prints go to stderr
    _serve(argv[0], int(argv[1]), int(argv[2]), sys.stdin.buffer, protocol)


if __name__ == "__main__":
    main(sys.argv[1:])
