"""Knowledge base: recall@1/@5 on the question set, search latency at 1k/10k chunks on SQLite
and PostgreSQL, ingest throughput (pages/s).

Latency stores are filled with synthetic chunks: the corpus's chunks with random word tails
and their vectors plus noise (unit length), so full-text and vector indexes see realistic
data without embedding 10k texts. Queries are the question set's, embedded each time.

Latency figures: "search" is ``KbService.search`` end to end (embed the question, both
rankings, fusion, fetch); "store" is ``Store.hybrid_search`` (everything but the embedding);
"rankings" is ``vector_search`` + ``text_search`` alone, as earlier versions measured "store".
"""

from __future__ import annotations

import argparse
import os
import shutil
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

CHUNKS_PER_DOC = 100  # synthetic documents of this many chunks
NOISE = 0.35  # std of the noise added to corpus vectors (before re-normalising)
SEED = 11
TOP_K = 5
CANDIDATES = 20  # chunks per ranking, as KbService.search takes for top_k 5


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--sizes", default="1000,10000", help="store sizes in chunks (comma-separated)")
    p.add_argument("--backends", default="sqlite,postgres", help="sqlite and/or postgres")
    p.add_argument("--queries", type=int, default=75, help="queries per latency case")


def _pct(values: list[float], q: float) -> float:
    return round(float(np.percentile(np.array(values) * 1000.0, q)), 2)


def _recall(service: Any, questions: list[dict[str, Any]]) -> dict[str, Any]:
    from sage_robot.kb.service import CORPUS_PREFIX

    out: dict[str, Any] = {}
    for part, subset in (("all", questions), ("heldout", [q for q in questions if q.get("heldout")])):
        at1 = at5 = 0
        for q in subset:
            sources = [p.source for p in service.search(q["q"], 5)]
            want = CORPUS_PREFIX + q["doc"]
            at1 += sources[:1] == [want]
            at5 += want in sources
        out[part] = {"questions": len(subset), "recall_at_1": round(at1 / len(subset), 3),
                     "recall_at_5": round(at5 / len(subset), 3)}
    return out


def _open(backend: str, folder: Path, dim: int, pg: dict[str, str]) -> Any:
    if backend == "sqlite":
        from sage_robot.kb.store.sqlite import SqliteStore

        return SqliteStore(folder / f"kb-{time.monotonic_ns()}.sqlite3", dim)
    import psycopg

    from sage_robot.kb.store.postgres import PostgresStore, start_embedded

    if "dsn" not in pg:
        pg["dsn"] = start_embedded(folder / "pg", cleanup="delete")
    schema = f"bench_{time.monotonic_ns()}"
    with psycopg.connect(pg["dsn"], autocommit=True) as conn:
        conn.execute("CREATE EXTENSION IF NOT EXISTS vector")
        conn.execute(f"CREATE SCHEMA {schema}")
    return PostgresStore(f"{pg['dsn']}&options=-csearch_path%3D{schema},public", dim)


def _fill(store: Any, size: int, rows: list[Any], vecs: np.ndarray, rng: np.random.Generator) -> float:
    from sage_robot.kb.store.base import NewChunk, NewDocument

    words = " ".join(r.text for r in rows).split()
    t0 = time.perf_counter()
    for d in range(0, size, CHUNKS_PER_DOC):
        n = min(CHUNKS_PER_DOC, size - d)
        pick = rng.integers(0, len(rows), n)
        chunks = [
            NewChunk(i, rows[j].text + " " + " ".join(rng.choice(words, 20)), rows[j].section, None)
            for i, j in enumerate(pick)
        ]
        v = vecs[pick] + rng.normal(0, NOISE / np.sqrt(vecs.shape[1]), (n, vecs.shape[1]))
        v = (v / np.linalg.norm(v, axis=1, keepdims=True)).astype(np.float32)
        store.replace_document(NewDocument(f"synthetic/{d}", "Synthetic", str(d), "md", 1, 0, 0.0), chunks, v)
    return time.perf_counter() - t0


def _latency(service: Any, questions: list[dict[str, Any]], n: int) -> dict[str, Any]:
    from sage_robot.kb.store.base import query_terms

    texts = [questions[i % len(questions)]["q"] for i in range(n)]
    service.search(texts[0], 5)  # warm caches (SQLite's vector matrix)
    total, store_only = [], []
    for text in texts:
        t0 = time.perf_counter()
        service.search(text, TOP_K)
        total.append(time.perf_counter() - t0)
    vecs = service.embedder.embed(texts)
    store = service.store
    rankings, vector_only, text_only = [], [], []
    for text, vec in zip(texts, vecs, strict=True):
        terms = query_terms(text)
        t0 = time.perf_counter()
        store.hybrid_search(vec, terms, CANDIDATES, TOP_K)  # what search asks of the store
        t1 = time.perf_counter()
        store.vector_search(vec, CANDIDATES)
        t2 = time.perf_counter()
        store.text_search(terms, CANDIDATES)
        t3 = time.perf_counter()
        store_only.append(t1 - t0)
        rankings.append(t3 - t1)
        vector_only.append(t2 - t1)
        text_only.append(t3 - t2)
    return {"search_p50_ms": _pct(total, 50), "search_p95_ms": _pct(total, 95),
            "store_p50_ms": _pct(store_only, 50), "store_p95_ms": _pct(store_only, 95),
            "rankings_p50_ms": _pct(rankings, 50), "rankings_p95_ms": _pct(rankings, 95),
            "vector_p95_ms": _pct(vector_only, 95), "text_p95_ms": _pct(text_only, 95)}


def run(args: argparse.Namespace) -> dict[str, Any]:
    import yaml

    from sage_robot.kb.embed import make_embedder
    from sage_robot.kb.service import CORPUS_DIR, KbService
    from sage_robot.kb.store.sqlite import SqliteStore

    questions = yaml.safe_load((CORPUS_DIR / "questions.yaml").read_text())
    folder = Path(tempfile.mkdtemp(prefix="sage-kb-bench-"))
    pg: dict[str, str] = {}
    try:
        t0 = time.perf_counter()
        embedder = make_embedder("all-MiniLM-L6-v2")
        load_s = time.perf_counter() - t0
        corpus = KbService(SqliteStore(folder / "corpus.sqlite3", embedder.dim), embedder)
        t0 = time.perf_counter()
        # Embeds every chunk (not ensure_corpus, which takes the shipped vectors).
        results = [corpus.ingest_file(path, source) for source, path in corpus.corpus_files().items()]
        ingest_s = time.perf_counter() - t0
        pages = sum(r.pages for r in results)
        chunks = sum(r.chunks for r in results)
        out: dict[str, Any] = {
            "bench": "kb",
            "embedder": embedder.name,
            "model_load_s": round(load_s, 2),
            "ingest": {"documents": len(results), "pages": pages, "chunks": chunks,
                       "seconds": round(ingest_s, 2), "pages_per_s": round(pages / ingest_s, 2),
                       "chunks_per_s": round(chunks / ingest_s, 1)},
            "recall": {"sqlite": _recall(corpus, questions)},
            "latency": [],
        }
        if "postgres" in args.backends:  # the same corpus (shipped vectors) on PostgreSQL
            pg_corpus = KbService(_open("postgres", folder, embedder.dim, pg), embedder)
            pg_corpus.ensure_corpus()
            out["recall"]["postgres"] = _recall(pg_corpus, questions)
            pg_corpus.close()
        n_chunks = corpus.store.count_chunks()
        ids = [cid for cid, _ in corpus.store.vector_search(np.zeros(embedder.dim, np.float32), n_chunks)]
        rows = list(corpus.store.get_chunks(ids).values())
        vecs = embedder.embed([r.text for r in rows])
        rng = np.random.default_rng(SEED)
        for backend in args.backends.split(","):
            for size in (int(s) for s in args.sizes.split(",")):
                store = _open(backend.strip(), folder, embedder.dim, pg)
                fill_s = _fill(store, size, rows, vecs, rng)
                case = {"backend": backend, "chunks": store.count_chunks(), "fill_s": round(fill_s, 1),
                        "load_avg_1min": round(os.getloadavg()[0], 2)}
                case.update(_latency(KbService(store, embedder), questions, args.queries))
                out["latency"].append(case)
                store.close()
        corpus.close()
        out["load_avg_1min"] = round(os.getloadavg()[0], 2)
        return out
    finally:
        if pg:
            from sage_robot.kb.store.postgres import stop_embedded

            stop_embedded(folder / "pg")
        shutil.rmtree(folder, ignore_errors=True)
