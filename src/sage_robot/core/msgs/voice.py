"""Voice and face messages. ``UiState`` keeps the seed's face protocol field names."""

from __future__ import annotations

from enum import Enum

from sage_robot.core.msgs.base import message


class Phase(str, Enum):
    IDLE = "idle"
    LISTENING = "listening"
    THINKING = "thinking"
    SPEAKING = "speaking"
    NAVIGATING = "navigating"
    ERROR = "error"


@message()
class UiState:
    """What the face shows: ``{type: "ui_state", phase, asr_partial, asr_final, llm_tokens,
    tts_viseme, error_msg}`` in the seed's JSON."""

    phase: Phase = Phase.IDLE
    asr_partial: str = ""
    asr_final: str = ""
    llm_tokens: str = ""
    tts_viseme: float = 0.0  # mouth opening 0..1
    error_msg: str = ""


@message()
class Doa:
    """Speaker direction, seed convention: 0° behind, 90° left, 180° front, 270° right."""

    stamp: float
    angle_deg: float
    source: str = "sim"  # "xvf3800", "sim" or "fixed"


@message("audio_common_msgs/msg/AudioData")
class AudioChunk:
    """A piece of the robot's speech for the web pages (and recordings).

    ``pcm`` is little-endian int16 mono at ``sample_rate`` Hz; ``viseme`` is the mouth
    opening 0..1 for this chunk; ``utterance`` counts the robot's utterances, so a page can
    tell where one ends; ``final`` marks the last chunk of an utterance.
    """

    stamp: float
    sample_rate: int
    pcm: bytes
    viseme: float = 0.0
    utterance: int = 0
    final: bool = False


@message()
class TurnLatency:
    """Per-turn latency breakdown, seconds after the wake word (NaN: the step did not happen).

    ``end_of_speech``: the VAD closed the utterance; ``stt_done``: the transcript was ready;
    ``first_token``: the brain's first sentence arrived; ``first_audio``: the first sample
    of the reply went to the speaker. ``reply_delay_s`` is end of speech → first audio.
    """

    stamp: float
    turn: int
    wake: float = 0.0
    end_of_speech: float = float("nan")
    stt_done: float = float("nan")
    first_token: float = float("nan")
    first_audio: float = float("nan")
    transcript: str = ""

    @property
    def reply_delay_s(self) -> float:
        return self.first_audio - self.end_of_speech
