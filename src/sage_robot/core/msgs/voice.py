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
