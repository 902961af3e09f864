"""The numpy all-MiniLM-L6-v2 gives sentence-transformers' vectors, and sane ones."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from sage_robot.core.errors import ConfigError
from sage_robot.kb import bert
from sage_robot.kb.embed import make_embedder

# Made by data/make_minilm_reference.py with sentence-transformers + torch, from the same
# package's files (normalize_embeddings=False: the model's own Normalize layer applies).
REFERENCE = Path(__file__).parent / "data" / "minilm_reference.json"


def test_same_vectors_as_sentence_transformers(real_embedder):
    ref = json.loads(REFERENCE.read_text())
    ours = real_embedder.embed(ref["sentences"])
    theirs = np.array(ref["embeddings"], dtype=np.float32)
    assert ours.shape == theirs.shape == (4, 384)
    assert np.abs(ours - theirs).max() < 1e-5


def test_paraphrases_are_closer_than_unrelated_sentences(real_embedder):
    a, b, c, d = real_embedder.embed(
        [
            "Where can I buy a coffee?",
            "Is there a café where I could get an espresso?",
            "The tensile tester pulls steel specimens until they break.",
            "Which machine measures how strong a metal bar is?",
        ]
    )
    assert a @ b > 0.5
    assert c @ d > 0.4
    assert a @ b > a @ c + 0.3
    assert c @ d > c @ b + 0.2


def test_vectors_are_unit_length_and_do_not_depend_on_the_batch(real_embedder):
    texts = [
        "short",
        "a much longer sentence that needs a lot more padding in its batch " * 3,
        "mid size text",
    ]
    together = real_embedder.embed(texts)
    alone = np.stack([real_embedder.embed_one(t) for t in texts])
    np.testing.assert_allclose(np.linalg.norm(together, axis=1), 1.0, atol=1e-5)
    np.testing.assert_allclose(together, alone, atol=1e-5)
    assert real_embedder.embed([]).shape == (0, 384)


def test_long_texts_are_truncated_not_refused(real_embedder):
    vec = real_embedder.embed_one("word " * 2000)
    assert vec.shape == (384,)
    assert np.isfinite(vec).all()


def test_unknown_embedder_names_the_known_ones():
    with pytest.raises(ConfigError, match="unknown embedder 'nope'; known: all-MiniLM-L6-v2"):
        make_embedder("nope")


def test_erf_matches_the_standard_library():
    x = np.linspace(-5, 5, 2001, dtype=np.float32)
    expected = np.array([math.erf(v) for v in x.astype(float)])
    assert np.abs(bert.erf(x.copy()) - expected).max() < 1e-6


def test_mean_pool_ignores_padding():
    hidden = np.array([[[1.0, 2.0], [3.0, 4.0], [100.0, 100.0]]], dtype=np.float32)
    mask = np.array([[1, 1, 0]])
    np.testing.assert_allclose(bert.mean_pool(hidden, mask), [[2.0, 3.0]])
