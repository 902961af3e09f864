"""The shipped corpus vectors (data/kb/vectors.npz) are current, and first runs use them."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from sage_robot.kb.chunk import chunk_blocks
from sage_robot.kb.embed import Embedder, text_key
from sage_robot.kb.extract import extract
from sage_robot.kb.service import KbService, embed_text, load_corpus_vectors
from sage_robot.kb.store.sqlite import SqliteStore

STALE = "data/kb/vectors.npz is stale: run  python -m sage_robot.kb.corpus_vectors"


class Counting(Embedder):
    def __init__(self, inner: Embedder) -> None:
        self.inner, self.name, self.dim, self.texts = inner, inner.name, inner.dim, 0

    def embed(self, texts: Sequence[str]) -> np.ndarray:
        self.texts += len(texts)
        return self.inner.embed(texts)


def corpus_texts() -> list[str]:
    texts = []
    for path in KbService.corpus_files().values():
        doc = extract(path.read_bytes(), path.name)
        texts += [embed_text(doc.title, c.section, c.text) for c in chunk_blocks(doc.blocks)]
    return texts


def test_vectors_file_matches_the_corpus_and_the_model(embedder):
    table = load_corpus_vectors(embedder.name)
    texts = corpus_texts()
    assert {text_key(t) for t in texts} == set(table), STALE
    fresh = embedder.embed(texts)
    stored = np.stack([table[text_key(t)] for t in texts])
    assert np.abs(fresh - stored).max() < 1e-5, STALE


def test_first_run_embeds_nothing_and_other_embedders_ignore_the_table(tmp_path, embedder):
    counting = Counting(embedder)
    service = KbService(SqliteStore(tmp_path / "kb.sqlite3", embedder.dim), counting)
    results = service.ensure_corpus()
    assert len(results) == 18
    assert all(r.status == "added" for r in results)
    assert counting.texts == 0  # every chunk came from the table
    service.search("coffee", 1)
    assert counting.texts == 1  # questions are embedded as usual
    service.close()
    assert load_corpus_vectors("some-other-model") == {}
