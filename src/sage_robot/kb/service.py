"""The knowledge base: ingest documents, hybrid search, list and delete.

Search fuses two rankings with reciprocal rank fusion (RRF): full-text (BM25 / ts_rank)
and vector similarity (all-MiniLM-L6-v2 cosine). RRF needs no score calibration between
the two: each chunk scores sum(1 / (RRF_K + rank)) over the lists it appears in
(:func:`~sage_robot.kb.store.base.rrf_fuse`; PostgreSQL fuses in its one search query).

Methods are blocking (model inference, database I/O); async callers run them with
``asyncio.to_thread``. Expected failures of ingest are values (:class:`IngestResult`).
"""

from __future__ import annotations

import hashlib
import os
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path, PurePath

import numpy as np

from sage_robot.core.config.areas import KbSettings
from sage_robot.core.errors import SageError
from sage_robot.core.msgs.kb import Passage
from sage_robot.kb.chunk import chunk_blocks
from sage_robot.kb.embed import CachedEmbedder, Embedder, make_embedder
from sage_robot.kb.extract import READERS, IngestError, extract
from sage_robot.kb.store.base import NewChunk, NewDocument, Store, query_terms

MIN_CANDIDATES = 20  # chunks taken from each ranking before fusion
MAX_TOP_K = 50
MAX_QUERY_CHARS = 2000
CORPUS_DIR = Path(__file__).resolve().parents[1] / "data" / "kb"
CORPUS_PREFIX = "corpus/"  # source names of the shipped documents
# Vectors of the shipped corpus's chunks, made by `python -m sage_robot.kb.corpus_vectors`
# (a test checks they are current), so the first run ingests in a second, not in minutes on
# a slow CPU.
CORPUS_VECTORS = CORPUS_DIR / "vectors.npz"


class SearchError(SageError):
    """A search request is malformed (empty query, top_k out of range)."""


@dataclass(frozen=True)
class IngestResult:
    source: str
    status: str  # "added", "replaced", "unchanged" or "failed"
    document_id: int = 0
    chunks: int = 0
    pages: int = 0
    message: str = ""

    @property
    def ok(self) -> bool:
        return self.status != "failed"

    def as_dict(self) -> dict[str, object]:
        return dict(self.__dict__)


def default_data_dir() -> Path:
    """``$SAGE_DATA_DIR``, else ``$XDG_DATA_HOME/sage``, else ``~/.local/share/sage``."""
    if os.environ.get("SAGE_DATA_DIR"):
        return Path(os.environ["SAGE_DATA_DIR"])
    base = os.environ.get("XDG_DATA_HOME") or str(Path.home() / ".local" / "share")
    return Path(base) / "sage"


def open_store(settings: KbSettings, dim: int) -> Store:
    """The store the settings name: SQLite file, PostgreSQL DSN, or an embedded PostgreSQL."""
    if settings.backend == "sqlite":
        from sage_robot.kb.store.sqlite import SqliteStore

        return SqliteStore(settings.path or default_data_dir() / "kb.sqlite3", dim)
    if settings.backend == "postgres":
        from sage_robot.kb.store.postgres import PostgresStore, start_embedded

        dsn = settings.dsn or start_embedded(default_data_dir() / "kb-pgdata")
        return PostgresStore(dsn, dim)
    raise SageError(f"kb.backend {settings.backend!r} is unknown; use 'sqlite' or 'postgres'")


class KbService:
    """Documents in, passages out. Thread-safe; blocking."""

    def __init__(self, store: Store, embedder: Embedder) -> None:
        store.check_embedder(embedder.name, embedder.dim)
        self.store, self.embedder = store, embedder

    @classmethod
    def from_settings(cls, settings: KbSettings) -> KbService:
        embedder = make_embedder(settings.embedder)
        return cls(open_store(settings, embedder.dim), embedder)

    def close(self) -> None:
        self.store.close()

    # ---------------------------------------------------------------- ingest
    def ingest_bytes(
        self, data: bytes, name: str, source: str | None = None, embedder: Embedder | None = None
    ) -> IngestResult:
        """Ingest one document; a changed one replaces its chunks, an unchanged one is skipped."""
        source = source or name
        try:
            return self._ingest(data, name, source, embedder or self.embedder)
        except IngestError as exc:
            return IngestResult(source, "failed", message=str(exc))

    def _ingest(self, data: bytes, name: str, source: str, embedder: Embedder) -> IngestResult:
        digest = hashlib.sha256(data).hexdigest()
        old = self.store.document_by_source(source)
        if old is not None and old.sha256 == digest:
            return IngestResult(source, "unchanged", old.id, old.chunks, old.pages)
        doc = extract(data, name)
        chunks = chunk_blocks(doc.blocks)
        vectors = embedder.embed([embed_text(doc.title, c.section, c.text) for c in chunks])
        info = self.store.replace_document(
            NewDocument(source, doc.title, digest, PurePath(name).suffix.lower().lstrip("."),
                        doc.pages, len(data), time.time()),
            [NewChunk(c.ordinal, c.text, c.section, c.page) for c in chunks],
            vectors,
        )
        status = "replaced" if old is not None else "added"
        return IngestResult(source, status, info.id, info.chunks, info.pages)

    def ingest_file(
        self, path: Path, source: str | None = None, embedder: Embedder | None = None
    ) -> IngestResult:
        source = source or str(path.resolve())
        try:
            data = path.read_bytes()
        except OSError as exc:
            return IngestResult(source, "failed", message=f"{path}: cannot read ({exc.strerror})")
        return self.ingest_bytes(data, path.name, source, embedder)

    def ingest_paths(
        self, paths: Iterable[Path], progress: Callable[[Path], None] | None = None
    ) -> list[IngestResult]:
        """Files and folders (recursively, supported types only); one result per file."""
        results = []
        for path in expand_paths(paths):
            results.append(self.ingest_file(path))
            if progress is not None:
                progress(path)
        return results

    @staticmethod
    def corpus_files(folder: Path = CORPUS_DIR) -> dict[str, Path]:
        """The shipped documents by source name (``corpus/places/cafe.md``)."""
        return {CORPUS_PREFIX + p.relative_to(folder).as_posix(): p for p in sorted(folder.rglob("*.md"))}

    def ensure_corpus(self, folder: Path = CORPUS_DIR) -> list[IngestResult]:
        """First run (empty store): ingest the shipped corpus. Later runs: refresh the shipped
        documents the store still has (a new SAGE version may have edited them; unchanged
        ones cost a hash), without re-adding the ones an operator deleted."""
        files = self.corpus_files(folder)
        docs = self.store.list_documents()
        if docs:
            present = {d.source for d in docs}
            files = {source: path for source, path in files.items() if source in present}
        cached = CachedEmbedder(self.embedder, load_corpus_vectors(self.embedder.name))
        return [self.ingest_file(path, source, cached) for source, path in files.items()]

    # ---------------------------------------------------------------- search
    def search(self, query: str, top_k: int = 5) -> list[Passage]:
        query = query.strip()
        if not query:
            raise SearchError("the query is empty")
        if len(query) > MAX_QUERY_CHARS:
            raise SearchError(f"the query is longer than {MAX_QUERY_CHARS} characters")
        if not 1 <= top_k <= MAX_TOP_K:
            raise SearchError(f"top_k must be between 1 and {MAX_TOP_K}, got {top_k}")
        n = max(MIN_CANDIDATES, 4 * top_k)
        hits = self.store.hybrid_search(self.embedder.embed_one(query), query_terms(query), n, top_k)
        return [
            Passage(
                text=h.chunk.text, source=h.chunk.source, title=h.chunk.title,
                section=h.chunk.section, score=round(h.score, 6),
                document_id=h.chunk.document_id, similarity=round(h.similarity, 4),
            )
            for h in hits
        ]

    # ------------------------------------------------------------- documents
    def list_documents(self) -> list[dict[str, object]]:
        return [d.as_dict() for d in self.store.list_documents()]

    def delete_document(self, document_id: int) -> bool:
        return self.store.delete_document(document_id)


def load_corpus_vectors(embedder_name: str, path: Path = CORPUS_VECTORS) -> dict[str, np.ndarray]:
    """The shipped corpus's vectors by text key, if they were made with this embedder."""
    if not path.is_file():
        return {}
    with np.load(path) as data:
        if str(data["embedder"]) != embedder_name:
            return {}
        return dict(zip((str(k) for k in data["keys"]), data["vectors"], strict=True))


def embed_text(title: str, section: str, text: str) -> str:
    """What the model sees for a chunk: where it is from, then the chunk."""
    where = section if section.startswith(title) else f"{title} > {section}" if section else title
    return f"{where}: {text}"


def expand_paths(paths: Iterable[Path]) -> list[Path]:
    """Files as given, plus the supported files found under folders (sorted). Missing paths
    are kept so ingest reports them."""
    out: list[Path] = []
    for path in paths:
        if path.is_dir():
            out.extend(sorted(p for p in path.rglob("*") if p.is_file() and p.suffix.lower() in READERS))
        else:
            out.append(path)
    return out


def passages_as_answer(query: str, passages: Sequence[Passage]) -> dict[str, object]:
    """The seed-compatible JSON answer of ``POST /api/kb/search``."""
    return {
        "query": query,
        "results": [
            {
                "content": p.text, "source": p.source, "title": p.title, "section": p.section,
                "score": p.score, "similarity": p.similarity, "document_id": p.document_id,
            }
            for p in passages
        ],
    }
