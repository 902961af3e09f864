"""Round trip of every voice message through the JSON codec (one example per type)."""

from __future__ import annotations

import json
import math

import pytest

from sage_robot.core.msgs import REGISTRY, from_dict, to_dict
from sage_robot.core.msgs.voice import AudioChunk, Doa, Phase, TurnLatency, UiState

EXAMPLES = [
    UiState(Phase.SPEAKING, "wh", "where is the lab", "It is", 0.42, ""),
    UiState(),
    Doa(12.5, 270.0, "xvf3800"),
    AudioChunk(3.25, 22050, b"\x01\x00\xff\x7f", 0.8, 3, True),
    TurnLatency(9.0, 2, 0.0, 1.9, 2.6, 2.9, 3.3, "where is the lab"),
]


@pytest.mark.parametrize("msg", EXAMPLES, ids=lambda m: type(m).__name__)
def test_round_trip_through_json(msg):
    wire = json.dumps(to_dict(msg))
    assert from_dict(json.loads(wire)) == msg


def test_every_voice_message_has_an_example():
    covered = {type(m).__name__ for m in EXAMPLES}
    mine = {n for n, c in REGISTRY.items() if c.__module__ == "sage_robot.core.msgs.voice"}
    assert mine <= covered, f"add round-trip examples for {sorted(mine - covered)}"


def test_ui_state_keeps_the_seed_face_protocol():
    d = to_dict(UiState(Phase.LISTENING, asr_partial="hel"))
    assert d == {"type": "UiState", "phase": "listening", "asr_partial": "hel", "asr_final": "",
                 "llm_tokens": "", "tts_viseme": 0.0, "error_msg": ""}  # fmt: skip


def test_missing_steps_stay_nan_through_json():
    msg = TurnLatency(1.0, 1, end_of_speech=2.0)
    back: TurnLatency = from_dict(json.loads(json.dumps(to_dict(msg))))
    assert math.isnan(back.first_audio)
    assert math.isnan(back.reply_delay_s)
    assert TurnLatency(1.0, 1, 0.0, 2.0, 2.5, 2.7, 2.9).reply_delay_s == pytest.approx(0.9)


def test_bad_audio_chunk_names_the_field():
    with pytest.raises(ValueError, match=r"AudioChunk.pcm"):
        from_dict({"type": "AudioChunk", "stamp": 0.0, "sample_rate": 16000, "pcm": "nope"})
