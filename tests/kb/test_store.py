"""The store contract, on SQLite and on a real PostgreSQL + pgvector (same tests)."""

from __future__ import annotations

import numpy as np
import pytest

from sage_robot.core.errors import ConfigError
from sage_robot.kb.store.base import NewChunk, NewDocument, query_terms

DIM = 384
# The chunk without text breaks a NOT NULL column: sqlite and postgres word it alike.
NOT_NULL = r"(?i)not[ -]null"


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
    assert store.document_by_source("a.md") == info
    assert store.document_by_source("b.md") is None
    hits = store.vector_search(vecs[1], 2)
    assert hits[0][1] == pytest.approx(1.0, abs=1e-5)
    assert len(hits) == 2
    rows = store.get_chunks([hits[0][0]])
    assert rows[hits[0][0]].text == "Robots charge at the dock."
    assert rows[hits[0][0]].source == "a.md"
    assert rows[hits[0][0]].section == "Part"
    found = store.text_search(query_terms("where do robots get charged?"), 5)  # stemmed: charged ~ charge
    assert [store.get_chunks(found)[i].text for i in found] == ["Robots charge at the dock."]
    assert store.text_search(query_terms("the of and"), 5) == []  # only stopwords: no match


def test_replace_keeps_id_and_swaps_chunks(store):
    rng = np.random.default_rng(2)
    first = store.replace_document(doc(sha="1"), chunks("old text about lathes"), unit(rng, 1))
    second = store.replace_document(
        doc(sha="2", title="Beta"), chunks("new text", "more new text"), unit(rng, 2)
    )
    assert second.id == first.id
    assert second.chunks == 2
    assert second.title == "Beta"
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
    assert store.text_search(["alpha"], 5) == []
    assert store.count_chunks() == 1
    assert [cid for cid, _ in store.vector_search(unit(rng, 1)[0], 5)] == list(
        store.get_chunks(store.text_search(["beta"], 5))
    )


def test_failed_write_leaves_the_store_as_it_was(store):
    rng = np.random.default_rng(4)
    before = store.replace_document(doc(sha="1"), chunks("kept text"), unit(rng, 1))
    broken = [NewChunk(0, "fine", "s", None), NewChunk(1, None, "s", None)]  # type: ignore[arg-type]
    with pytest.raises(Exception, match=NOT_NULL):  # each database raises its own error type
        store.replace_document(doc(sha="2"), broken, unit(rng, 2))
    assert store.list_documents() == [before]
    assert len(store.text_search(["kept"], 5)) == 1
    assert store.text_search(["fine"], 5) == []
    with pytest.raises(ValueError, match="expected vectors of shape"):
        store.replace_document(doc(sha="3"), chunks("x"), unit(rng, 2))


def test_store_refuses_vectors_of_another_model(store):
    store.check_embedder("model-a", DIM)
    store.check_embedder("model-a", DIM)
    with pytest.raises(ConfigError, match="built with model-a, not model-b"):
        store.check_embedder("model-b", DIM)


# ------------------------------------------------------------ PostgreSQL only
@pytest.fixture
def pg_store(pg_dsn):
    from sage_robot.kb.store.postgres import PostgresStore

    s = PostgresStore(pg_dsn, DIM)
    yield s
    s.close()


def lexeme_counts(dsn: str) -> tuple[dict[str, int], dict[str, int]]:
    """(kb_lexemes as kept by the store, the same counted from scratch with ts_stat)."""
    import psycopg

    with psycopg.connect(dsn) as conn:
        kept: dict[str, int] = dict(conn.execute("SELECT lexeme, df FROM kb_lexemes").fetchall())
        fresh: dict[str, int] = dict(
            conn.execute("SELECT word, ndoc FROM ts_stat('SELECT tsv FROM kb_chunks')").fetchall()
        )
    return kept, fresh


def test_pg_lexeme_frequencies_follow_every_write(pg_store, pg_dsn):
    rng = np.random.default_rng(5)
    a = pg_store.replace_document(
        doc("a.md", title="Shop"), chunks("lathes cut metal", "metal dust"), unit(rng, 2)
    )
    pg_store.replace_document(doc("b.md", title="Frames"), chunks("metal frames"), unit(rng, 1))
    kept, fresh = lexeme_counts(pg_dsn)
    assert kept == fresh
    assert kept["metal"] == 3
    assert kept["lath"] == 1
    assert kept["shop"] == 2
    pg_store.replace_document(doc("a.md", sha="2", title="Shop"), chunks("drills"), unit(rng, 1))
    kept, fresh = lexeme_counts(pg_dsn)
    assert kept == fresh
    assert kept["metal"] == 1
    assert "lath" not in kept
    assert kept["drill"] == 1
    with pytest.raises(Exception, match=NOT_NULL):  # a failed write leaves the counts alone too
        pg_store.replace_document(doc("a.md", sha="3"), [NewChunk(0, None, "s", None)], unit(rng, 1))  # type: ignore[arg-type]
    assert lexeme_counts(pg_dsn)[0] == kept
    assert pg_store.delete_document(a.id)
    kept, fresh = lexeme_counts(pg_dsn)
    assert kept == fresh
    assert "drill" not in kept
    assert pg_store.delete_document(a.id) is False
    assert lexeme_counts(pg_dsn)[0] == kept


def test_pg_store_made_before_lexeme_counts_gets_them_on_open(pg_store, pg_dsn):
    import psycopg

    from sage_robot.kb.store.postgres import PostgresStore

    vecs = unit(np.random.default_rng(6), 2)
    pg_store.replace_document(doc(), chunks("robots charge at the dock", "robots roam"), vecs)
    with psycopg.connect(pg_dsn, autocommit=True) as conn:
        conn.execute("DROP TABLE kb_lexemes")
    reopened = PostgresStore(pg_dsn, DIM)
    kept, fresh = lexeme_counts(pg_dsn)
    assert kept == fresh
    assert kept["robot"] == 2
    assert len(reopened.text_search(["robots"], 5)) == 2
    reopened.close()


def test_pg_full_text_ranks_the_candidates_of_the_rarest_words(pg_store, monkeypatch):
    from sage_robot.kb.store import postgres

    texts = [f"robots in room {i}" for i in range(6)] + ["robots near the lathe", "a lathe alone"]
    pg_store.replace_document(doc(), chunks(*texts), unit(np.random.default_rng(7), len(texts)))
    ids = {row.text: cid for cid, row in pg_store.get_chunks(range(1, 100)).items()}
    # Enough budget: every chunk with either word is ranked; both words beat one.
    assert pg_store.text_search(["robots", "lathe"], 3)[0] == ids["robots near the lathe"]
    assert len(pg_store.text_search(["robots", "lathe"], 20)) == 8
    # Budget 2: "lathe" (2 chunks) chooses the candidates; "robots" (7) still ranks them.
    monkeypatch.setattr(postgres, "FTS_CANDIDATES", 2)
    found = pg_store.text_search(["robots", "lathe"], 20)
    assert found == [ids["robots near the lathe"], ids["a lathe alone"]]
    assert len(pg_store.text_search(["robots"], 20)) == 7  # the rarest word is always taken
    assert pg_store.text_search(["unicorns"], 20) == []


def test_pg_pick_rare():
    from sage_robot.kb.store.postgres import pick_rare

    counts = [("weekday", 40), ("close", 300), ("build", 900)]
    assert pick_rare(counts, 500) == ["weekday", "close"]
    assert pick_rare(counts, 2000) == ["weekday", "close", "build"]
    assert pick_rare([("build", 900)], 500) == ["build"]
    assert pick_rare([], 500) == []


def test_pg_searches_use_the_indexes(pg_store):
    from sage_robot.kb.store.postgres import TEXT_SQL, VECTOR_SQL

    rng = np.random.default_rng(8)
    words = np.array(["alpha", "beta", "gamma", "delta", "epsilon", "zeta", "eta", "theta"])
    for d in range(2):  # 600 chunks: enough that scanning them all costs more than an index
        texts = [" ".join(rng.choice(words, 6)) + f" item{d}x{i}" for i in range(300)]
        pg_store.replace_document(doc(f"{d}.md", title="T"), chunks(*texts), unit(rng, 300))
    db = pg_store._db
    db.execute("ANALYZE kb_chunks")
    vec = unit(rng, 1)[0]
    plan = "\n".join(r[0] for r in db.execute("EXPLAIN " + VECTOR_SQL, (vec, vec, 20)))
    assert "kb_chunks_hnsw" in plan
    plan = "\n".join(r[0] for r in db.execute("EXPLAIN " + TEXT_SQL, ("item1x7 | alpha", "'item1x7'", 20)))
    assert "kb_chunks_tsv" in plan
    assert "Seq Scan" not in plan
    settings = dict(db.execute("SELECT name, setting FROM pg_settings WHERE name IN "
                               "('jit', 'max_parallel_workers_per_gather', 'hnsw.ef_search')").fetchall())
    assert settings == {"jit": "off", "max_parallel_workers_per_gather": "0", "hnsw.ef_search": "100"}
