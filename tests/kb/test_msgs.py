"""Round trip of the KB's bus messages through the JSON codec (STYLE 1)."""

from __future__ import annotations

import json

import pytest

from sage_robot.core.msgs import REGISTRY, from_dict, to_dict
from sage_robot.core.msgs.kb import Passage, SearchRequest, SearchResponse

EXAMPLES = [
    SearchRequest("where is the café?", 3),
    Passage(
        "Open 7:30 to 2:00.",
        "corpus/places/guelly_delly.md",
        "Guelly Delly café",
        "Guelly Delly café > Opening hours",
        0.0325,
        7,
        0.61,
    ),
    SearchResponse((Passage("a", "b"), Passage("c", "d", score=0.5, similarity=-0.1))),
    SearchResponse(),
]


@pytest.mark.parametrize("msg", EXAMPLES, ids=lambda m: type(m).__name__)
def test_round_trip(msg):
    assert from_dict(json.loads(json.dumps(to_dict(msg)))) == msg


def test_every_kb_message_has_an_example():
    kb = {n for n, c in REGISTRY.items() if c.__module__ == "sage_robot.core.msgs.kb"}
    assert kb <= {type(m).__name__ for m in EXAMPLES}


def test_bad_field_is_named():
    with pytest.raises(ValueError, match=r"SearchRequest.top_k: expected an integer"):
        from_dict({"type": "SearchRequest", "query": "x", "top_k": "five"})
