"""The microphone's last seconds, and where a wake phrase ended in them.

openWakeWord detects "Hey Jarvis" a frame or a few after the phrase ends (its score jumps
when the whole phrase is inside the model's window; the detector then needs its smoothing
and patience). A visitor who runs on ("Hey Jarvis, where is the cafe") is already saying
the question by then, so the utterance cannot start at the detection: :class:`MicHistory`
keeps every frame of the last :data:`HISTORY_S` with the wake models' raw scores, and
:meth:`MicHistory.after_wake` returns the frames from the end of the wake phrase on, which
the pipeline replays into the VAD and the recorder.

The end of the phrase is located on the score of the model that woke: the frame where it
rose to half its peak (the *rise*; walking back from the peak through frames at that level),
never more than :data:`MAX_CUT_BEFORE_DETECTION_S` before the detection (in noise the
score can hover at half its low peak through the whole phrase). The rise frame holds the
phrase's last sound, and the question's first one may be in the frame before it (the score
rises up to a frame after the phrase ends): the VAD starts on the rise frame (one frame of
the phrase's tail cannot start an utterance: that takes two frames of speech in a row),
and :data:`LEAD_IN_S` before it go into the recorder's pre-roll only, so Whisper hears
them when the question follows at once and they are pushed out of the pre-roll by the
silence when the visitor pauses. Measured with the real
models on "Hey Jarvis, where is the cafe" in one breath: as files (Piper at three speeds,
with and without the comma, four espeak-ng voices at two rates, 14 clips), from the
detection + 0.24 s (the old skip) Whisper heard the whole question on 1 clip ("the cap.",
"Happy.", "There is no cafe."), from the rise frame's start on 13, from a frame earlier on
14, two frames earlier the phrase's tail came through ("us where's the cafe."). Through the
pipeline on the simulated clock (eight renderings, each at five offsets on the 80 ms grid):
a lead-in of 0.08 s heard 38 of 40, 0.12 s all 40; "Hey Jarvis." then a pause of 0.1 to
0.9 s then the question: every one of 35 (the lead-in is gone from the pre-roll by then).
What little of the phrase may still come through is stripped from the transcript by
:func:`strip_wake_phrase`.
"""

from __future__ import annotations

import re
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from sage_robot.core.audio import FRAME_S, SAMPLE_RATE_HZ

HISTORY_S = 1.2  # microphone audio kept (s): where the score peaked, and the replay
RISE_LEVEL = 0.5  # of the score's peak: the frame it first reaches is the rise
LEAD_IN_S = 0.12  # audio before the rise frame in the pre-roll (not judged by the VAD)
MAX_CUT_BEFORE_DETECTION_S = 0.44  # the utterance never starts earlier than this before it
# Whisper's spellings of the wake phrases ("hey jarvis" heard as "Hey, Jarvis!", "Jervis", ...)
WAKE_WORD_VARIANTS: dict[str, tuple[str, ...]] = {
    "jarvis": ("jarvis", "jarvis's", "jervis", "jarvus", "javis", "charvis", "darvis", "jarves"),
    "alexa": ("alexa",),
}
GREETINGS = ("hey", "hi", "hay", "a", "ok", "okay")
WAKE_ONLY = "wake_phrase"  # Transcript.rejected: all Whisper heard was the wake phrase


@dataclass(frozen=True)
class HeardFrame:
    """One microphone frame: its samples, capture time and the wake models' raw scores."""

    pcm: np.ndarray
    time_s: float
    scores: Mapping[str, float]


class MicHistory:
    """The last :data:`HISTORY_S` of microphone frames (see module doc)."""

    def __init__(self, seconds: float = HISTORY_S) -> None:
        self._frames: deque[HeardFrame] = deque(maxlen=max(1, round(seconds / FRAME_S)))

    def __len__(self) -> int:
        return len(self._frames)

    def append(self, pcm: np.ndarray, time_s: float, scores: Mapping[str, float]) -> None:
        self._frames.append(HeardFrame(pcm, time_s, dict(scores)))

    def clear(self) -> None:
        self._frames.clear()

    def after_wake(self, model: str) -> tuple[list[HeardFrame], list[HeardFrame]]:
        """Where ``model``'s wake phrase ended: (the lead-in frames for the pre-roll, the
        frames from the rise on for the VAD); the last one appended (the detection's) is
        always in the second."""
        frames = list(self._frames)
        if not frames:
            return [], []
        rise = wake_phrase_end([f.scores.get(model, 0.0) for f in frames])
        lead_in: list[HeardFrame] = []
        need = round(LEAD_IN_S * SAMPLE_RATE_HZ)
        for f in reversed(frames[:rise]):
            if need <= 0:
                break
            lead_in.insert(0, HeardFrame(f.pcm[-need:], f.time_s, f.scores) if len(f.pcm) > need else f)
            need -= len(f.pcm)
        return lead_in, frames[rise:]


def wake_phrase_end(scores: list[float]) -> int:
    """Index of the rise frame (the wake phrase's last) of a detection that came on the last
    frame of ``scores`` (one raw score per frame, oldest first)."""
    last = len(scores) - 1
    frames_back = round((MAX_CUT_BEFORE_DETECTION_S - LEAD_IN_S) / FRAME_S)
    earliest = max(0, last - frames_back + 1)
    peak = int(np.argmax(scores))
    level = RISE_LEVEL * scores[peak]
    rise = peak
    while rise > 0 and scores[rise - 1] >= level:
        rise -= 1
    return min(last, max(earliest, rise))


def _wake_pattern() -> re.Pattern[str]:
    greet = "|".join(GREETINGS)
    names = "|".join(re.escape(v) for vs in WAKE_WORD_VARIANTS.values() for v in vs)
    return re.compile(rf"^\W*(?:(?:{greet})\W+)?(?:{names})\b\W*", re.IGNORECASE)


WAKE_PHRASE = _wake_pattern()


def strip_wake_phrase(text: str) -> str:
    """The transcript without a wake phrase at its start ("Hey Jarvis, where is the cafe?"
    → "where is the cafe?"); a transcript that is only the phrase becomes ""."""
    rest = WAKE_PHRASE.sub("", text, count=1)
    if rest == text:
        return text
    return rest[:1].upper() + rest[1:] if rest else ""
