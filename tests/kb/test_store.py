"""The store contract, on SQLite and on a real PostgreSQL + pgvector (same tests)."""

from __future__ import annotations

import numpy as np
import pytest

from sage_robot.core.errors import ConfigError
from sage_robot.kb.store.base import NewChunk, NewDocument, query_terms

DIM = 384


def doc(source: str = "a.md", sha: str = "1", title: str = "Alpha") -> NewDocument:
    return NewDocument(source, title, sha, "md", 1, 10, 1000.0)


def unit(rng: np.random.Generator, n: int) -> np.ndarray:
    v = rng.standard_normal((n, DIM)).astype(np.float32)
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def chunks(*texts: str) -> list[NewChunk]:
    return [NewChunk(i, t, "Part", None) for i, t in enumerate(texts)]


def test_insert_list_and_find(store):
    rng = np.random.default_rng(1)
    vecs = unit(rng, 2)
    info = store.replace_document(doc(), chunks("The café sells bagels.", "Robots charge at the dock."), vecs)
    assert (info.source, info.title, info.chunks) == ("a.md", "Alpha", 2)
    assert store.list_documents() == [info]
    assert store.document_by_source("a.md") == info and store.document_by_source("b.md") is None
    hits = store.vector_search(vecs[1], 2)
    assert hits[0][1] == pytest.approx(1.0, abs=1e-5) and len(hits) == 2
    rows = store.get_chunks([hits[0][0]])
    assert rows[hits[0][0]].text == "Robots charge at the dock."
    assert rows[hits[0][0]].source == "a.md" and rows[hits[0][0]].section == "Part"
    found = store.text_search(query_terms("where do robots get charged?"), 5)  # stemmed: charged ~ charge
    assert [store.get_chunks(found)[i].text for i in found] == ["Robots charge at the dock."]
    assert store.text_search(query_terms("the of and"), 5) == []  # only stopwords: no match


def test_replace_keeps_id_and_swaps_chunks(store):
    rng = np.random.default_rng(2)
    first = store.replace_document(doc(sha="1"), chunks("old text about lathes"), unit(rng, 1))
    second = store.replace_document(
        doc(sha="2", title="Beta"), chunks("new text", "more new text"), unit(rng, 2)
    )
    assert second.id == first.id and second.chunks == 2 and second.title == "Beta"
    assert store.count_chunks() == 2
    assert store.text_search(["lathes"], 5) == []
    assert len(store.text_search(["new"], 5)) == 2


def test_delete_removes_document_and_chunks(store):
    rng = np.random.default_rng(3)
    a = store.replace_document(doc("a.md", title="Apple"), chunks("alpha words"), unit(rng, 1))
    b = store.replace_document(doc("b.md", title="Banana"), chunks("beta words"), unit(rng, 1))
    assert store.delete_document(a.id) is True
    assert store.delete_document(a.id) is False
    assert [d.id for d in store.list_documents()] == [b.id]
    assert store.text_search(["alpha"], 5) == [] and store.count_chunks() == 1
    assert [cid for cid, _ in store.vector_search(unit(rng, 1)[0], 5)] == list(
        store.get_chunks(store.text_search(["beta"], 5))
    )


def test_failed_write_leaves_the_store_as_it_was(store):
    rng = np.random.default_rng(4)
    before = store.replace_document(doc(sha="1"), chunks("kept text"), unit(rng, 1))
    broken = [NewChunk(0, "fine", "s", None), NewChunk(1, None, "s", None)]  # type: ignore[arg-type]
    with pytest.raises(Exception):  # noqa: B017 - each database raises its own error type
        store.replace_document(doc(sha="2"), broken, unit(rng, 2))
    assert store.list_documents() == [before]
    assert len(store.text_search(["kept"], 5)) == 1 and store.text_search(["fine"], 5) == []
    with pytest.raises(ValueError, match="expected vectors of shape"):
        store.replace_document(doc(sha="3"), chunks("x"), unit(rng, 2))


def test_store_refuses_vectors_of_another_model(store):
    store.check_embedder("model-a", DIM)
    store.check_embedder("model-a", DIM)
    with pytest.raises(ConfigError, match="built with model-a, not model-b"):
        store.check_embedder("model-b", DIM)
