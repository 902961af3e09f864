"""Voice activity: Silero VAD (ONNX) in streaming form, and the end-of-utterance logic.

:class:`SileroVad` gives the speech probability of each 32 ms window (512 samples at
16 kHz, with the model's 64-sample context and recurrent state carried between calls).
The model file is the one faster-whisper ships (``assets/silero_vad_v6.onnx``); a path
can be given instead.

:class:`UtteranceRecorder` turns frames + probabilities into one utterance: it keeps a
pre-roll so the first syllable is not lost, ends after ``silence_s`` of silence, and cuts
at ``max_s``.
"""

from __future__ import annotations

import enum
from collections import deque
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sage_robot.core.audio import FRAME_S, SAMPLE_RATE_HZ
from sage_robot.core.errors import ConfigError
from sage_robot.voice.audio_io import to_float

WINDOW_SAMPLES = 512  # 32 ms at 16 kHz: Silero's window
CONTEXT_SAMPLES = 64  # samples of the previous window the model sees
STATE_SHAPE = (1, 1, 128)  # the model's recurrent state (h and c)
MIN_SPEECH_S = 0.16  # shorter bursts over threshold (a cough, a click) do not start speech


def silero_model_path() -> Path:
    """The Silero VAD ONNX file shipped with faster-whisper."""
    try:
        import faster_whisper
    except ImportError:
        raise ConfigError("the VAD needs faster-whisper: pip install 'sage-robot[voice]'") from None
    path = Path(faster_whisper.__file__).parent / "assets" / "silero_vad_v6.onnx"
    if not path.is_file():
        raise ConfigError(f"Silero VAD model not found at {path}; reinstall faster-whisper")
    return path


class SileroVad:
    """Streaming speech probability, one value per 32 ms window."""

    def __init__(self, model_path: str | Path | None = None) -> None:
        try:
            import onnxruntime as ort
        except ImportError:
            raise ConfigError("the VAD needs onnxruntime: pip install 'sage-robot[voice]'") from None
        opts = ort.SessionOptions()
        opts.inter_op_num_threads = 1
        opts.intra_op_num_threads = 1
        opts.log_severity_level = 4
        path = Path(model_path) if model_path else silero_model_path()
        self._session = ort.InferenceSession(str(path), sess_options=opts,
                                             providers=["CPUExecutionProvider"])  # fmt: skip
        self.reset()

    def reset(self) -> None:
        self._h = np.zeros(STATE_SHAPE, dtype=np.float32)
        self._c = np.zeros(STATE_SHAPE, dtype=np.float32)
        self._context = np.zeros(CONTEXT_SAMPLES, dtype=np.float32)
        self._pending = np.zeros(0, dtype=np.float32)

    def window(self, x: np.ndarray) -> float:
        """Probability of speech in one 512-sample window (float in [-1, 1])."""
        inp = np.concatenate([self._context, x])[None, :].astype(np.float32)
        out, self._h, self._c = self._session.run(None, {"input": inp, "h": self._h, "c": self._c})
        self._context = x[-CONTEXT_SAMPLES:]
        return float(np.asarray(out).reshape(-1)[0])

    def probabilities(self, chunk: np.ndarray) -> list[float]:
        """Push audio of any length; one probability per completed window."""
        self._pending = np.concatenate([self._pending, to_float(chunk)])
        n = len(self._pending) // WINDOW_SAMPLES
        probs = [self.window(self._pending[i * WINDOW_SAMPLES : (i + 1) * WINDOW_SAMPLES])
                 for i in range(n)]  # fmt: skip
        self._pending = self._pending[n * WINDOW_SAMPLES :]
        return probs

    def frame_probability(self, chunk: np.ndarray) -> float:
        """The highest probability among the windows this chunk completed (0 if none)."""
        probs = self.probabilities(chunk)
        return max(probs) if probs else 0.0

    def speech_seconds(self, pcm: np.ndarray, threshold: float) -> float:
        """How much of a whole clip is speech (state is reset before and after)."""
        self.reset()
        probs = self.probabilities(pcm)
        self.reset()
        return sum(p >= threshold for p in probs) * WINDOW_SAMPLES / SAMPLE_RATE_HZ


class EndReason(str, enum.Enum):
    SILENCE = "silence"  # the visitor stopped speaking
    MAX_LENGTH = "max_length"  # cut at the longest utterance allowed
    NO_SPEECH = "no_speech"  # nobody started speaking in time


@dataclass(frozen=True)
class Utterance:
    """A finished utterance: 16 kHz int16 audio (pre-roll included)."""

    pcm: np.ndarray
    reason: EndReason
    speech_s: float  # seconds of frames judged speech


class UtteranceRecorder:
    """Collects one utterance from 80 ms frames and their speech probabilities."""

    def __init__(
        self,
        threshold: float = 0.6,
        silence_s: float = 0.7,
        preroll_s: float = 0.4,
        max_s: float = 15.0,
        start_timeout_s: float = 5.0,
    ) -> None:
        self.threshold, self.silence_s, self.max_s = threshold, silence_s, max_s
        self.start_timeout_s = start_timeout_s
        self._preroll: deque[np.ndarray] = deque(maxlen=max(1, round(preroll_s / FRAME_S)))
        self.reset()

    def reset(self) -> None:
        self._preroll.clear()
        self._frames: list[np.ndarray] = []
        self._run_s = 0.0  # consecutive speech before start
        self._started = False
        self._silent_s = 0.0
        self._waited_s = 0.0
        self._speech_s = 0.0

    @property
    def started(self) -> bool:
        return self._started

    @property
    def silent_s(self) -> float:
        """Silence since the last speech frame of a started utterance (s)."""
        return self._silent_s

    @property
    def speech_s(self) -> float:
        """Speech so far; it grows only when the visitor speaks (a version number)."""
        return self._speech_s

    @property
    def duration_s(self) -> float:
        """Audio recorded so far, pre-roll included (s); 0 before speech starts."""
        return len(self._frames) * FRAME_S

    def snapshot(self) -> np.ndarray:
        """The utterance so far (pre-roll included)."""
        return np.concatenate(self._frames) if self._frames else np.zeros(0, dtype=np.int16)

    def lead_in(self, frame: np.ndarray) -> None:
        """Audio before the first frame to be judged: into the pre-roll only (it is part of
        the utterance if speech starts within the pre-roll's length)."""
        if not self._started:
            self._preroll.append(frame)

    def push(self, frame: np.ndarray, prob: float) -> Utterance | None:
        """Add one frame; returns the utterance when it has ended."""
        speech = prob >= self.threshold
        if not self._started:
            self._preroll.append(frame)
            self._waited_s += FRAME_S
            self._run_s = self._run_s + FRAME_S if speech else 0.0
            if self._run_s >= MIN_SPEECH_S - 1e-9:
                self._started = True
                self._frames = list(self._preroll)
                self._speech_s = self._run_s
            elif self._waited_s >= self.start_timeout_s:
                return self._finish(EndReason.NO_SPEECH)
            return None
        self._frames.append(frame)
        if speech:
            self._speech_s += FRAME_S
            self._silent_s = 0.0
        else:
            self._silent_s += FRAME_S
        if self._silent_s >= self.silence_s - 1e-9:
            return self._finish(EndReason.SILENCE)
        if len(self._frames) * FRAME_S >= self.max_s - 1e-9:
            return self._finish(EndReason.MAX_LENGTH)
        return None

    def _finish(self, reason: EndReason) -> Utterance:
        frames = self._frames if self._started else []
        pcm = np.concatenate(frames) if frames else np.zeros(0, dtype=np.int16)
        utt = Utterance(pcm, reason, self._speech_s)
        self.reset()
        return utt
