"""The knowledge base: ingest documents, hybrid search, list and delete.

Search fuses two rankings with reciprocal rank fusion (RRF): full-text (BM25 / ts_rank)
and vector similarity (all-MiniLM-L6-v2 cosine). RRF needs no score calibration between
the two: each chunk scores sum(1 / (RRF_K + rank)) over the lists it appears in
(:func:`~sage_robot.kb.store.base.rrf_fuse`; PostgreSQL fuses in its one search query).

Methods are blocking (model inference, database I/O); async callers run them with
``asyncio.to_thread``. Expected failures of ingest are values (:class:`IngestResult`).
A batch ingest reports its progress and can be cancelled (:mod:`sage_robot.kb.progress`);
each document costs bounded memory (:mod:`sage_robot.kb.guard`).
"""

from __future__ import annotations

import hashlib
import os
import threading
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path, PurePath
from typing import BinaryIO

import numpy as np

from sage_robot.core.config.areas import KbSettings
from sage_robot.core.errors import SageError
from sage_robot.core.msgs.kb import Passage
from sage_robot.kb.chunk import Chunk, chunk_blocks
from sage_robot.kb.embed import CachedEmbedder, Embedder, make_embedder
from sage_robot.kb.extract import READERS, IngestError, extract
from sage_robot.kb.guard import IngestLimits, check_size
from sage_robot.kb.progress import IngestBusy, IngestCancelled, IngestProgress, IngestRun
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
# Chunks embedded at a time: the memory of one forward pass stays small, and progress and
# cancel are seen between batches (about 3 s of one CPU core per batch).
EMBED_BATCH = 32


__all__ = ["IngestBusy", "IngestCancelled", "IngestLimits", "IngestProgress", "IngestRun", "KbService"]


class SearchError(SageError):
    """A search request is malformed (empty query, top_k out of range)."""


@dataclass(frozen=True)
class IngestResult:
    source: str
    status: str  # "added", "replaced", "unchanged", "failed" or "cancelled" (not stored)
    document_id: int = 0
    chunks: int = 0
    pages: int = 0
    message: str = ""

    @property
    def ok(self) -> bool:
        return self.status in ("added", "replaced", "unchanged")

    def as_dict(self) -> dict[str, object]:
        return dict(self.__dict__)


@dataclass(frozen=True)
class PendingDocument:
    """A document waiting to be ingested: bytes in memory, a file, or an open binary stream
    (an upload); read only when its turn comes, at most the size limit plus one byte."""

    name: str  # file name: its extension picks the reader
    source: str  # the store's key for it
    data: bytes | None = None
    path: Path | None = None
    stream: BinaryIO | None = None

    def read(self, limits: IngestLimits) -> bytes:
        """The bytes; IngestError if they cannot be read or are over the size limit."""
        if self.data is not None:
            check_size(len(self.data), self.name, limits)
            return self.data
        if self.path is not None:
            try:
                with self.path.open("rb") as f:
                    return _read_bounded(f, os.fstat(f.fileno()).st_size, self.name, limits)
            except OSError as exc:
                raise IngestError(f"{self.path}: cannot read ({exc.strerror})") from None
        if self.stream is not None:
            size = None
            if self.stream.seekable():
                size = self.stream.seek(0, os.SEEK_END)
                self.stream.seek(0)
            return _read_bounded(self.stream, size, self.name, limits)
        raise ValueError("a PendingDocument needs data, a path or a stream")


def _read_bounded(f: BinaryIO, size: int | None, name: str, limits: IngestLimits) -> bytes:
    """At most the size limit plus one byte of ``f``; the announced ``size`` is checked first
    (nothing is read when it is over) and sizes the read, as a file may still grow."""
    if size is not None:
        check_size(size, name, limits)
    cap = limits.max_document_bytes + 1
    data = f.read(min(size + 1, cap) if size is not None else cap)
    if size is not None and len(data) > size:  # it grew since: read on, up to the cap
        data += f.read(cap - len(data))
    check_size(len(data), name, limits)
    return data


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

    def __init__(self, store: Store, embedder: Embedder, limits: IngestLimits | None = None) -> None:
        store.check_embedder(embedder.name, embedder.dim)
        self.store, self.embedder = store, embedder
        self.limits = limits or IngestLimits()
        self._run: IngestRun | None = None  # the latest batch ingest
        self._run_lock = threading.Lock()

    @classmethod
    def from_settings(cls, settings: KbSettings) -> KbService:
        embedder = make_embedder(settings.embedder)
        return cls(open_store(settings, embedder.dim), embedder, IngestLimits.from_settings(settings))

    def close(self) -> None:
        self.store.close()

    # ---------------------------------------------------------------- ingest
    def begin_ingest(self, documents: int) -> IngestRun:
        """Register a batch of ``documents`` as this service's ingest (see :meth:`progress`);
        IngestBusy while another one runs."""
        with self._run_lock:
            if self._run is not None:
                now = self._run.snapshot()
                if now.running:
                    raise IngestBusy(
                        f"an ingest is already running ({now.documents_done} of "
                        f"{now.documents_total} documents done); wait for it or cancel it"
                    )
            self._run = IngestRun(documents)
            return self._run

    def progress(self) -> IngestProgress:
        """The running (or latest) batch ingest; state ``idle`` if there was none."""
        run = self._run
        return run.snapshot() if run is not None else IngestProgress()

    def cancel_ingest(self) -> bool:
        """Cancel the running batch ingest; False if none runs."""
        run = self._run
        return run.cancel() if run is not None else False

    def ingest_documents(
        self, docs: Sequence[PendingDocument], run: IngestRun | None = None
    ) -> list[IngestResult]:
        """Ingest a batch, one document after the other, with progress and cancel in ``run``
        (from :meth:`begin_ingest`; begun here if not given). One result per document: a
        failed one does not stop the others; after a cancel, the document being read and the
        ones after it are ``cancelled`` and not stored (those before it stay)."""
        run = run or self.begin_ingest(len(docs))
        results: list[IngestResult] = []
        try:
            for doc in docs:
                if run.cancelled:
                    results.append(IngestResult(doc.source, "cancelled", message=f"{doc.name}: cancelled"))
                    continue
                run.start_document(doc.name)
                result = self._ingest_pending(doc, self.embedder, run)
                results.append(result)
                if result.status != "cancelled":
                    run.document_done(failed=result.status == "failed")
        finally:
            run.finish()
        return results

    def ingest_bytes(
        self, data: bytes, name: str, source: str | None = None, embedder: Embedder | None = None
    ) -> IngestResult:
        """Ingest one document; a changed one replaces its chunks, an unchanged one is skipped."""
        doc = PendingDocument(name, source or name, data=data)
        return self._ingest_pending(doc, embedder or self.embedder, IngestRun(1))

    def ingest_file(
        self, path: Path, source: str | None = None, embedder: Embedder | None = None
    ) -> IngestResult:
        doc = PendingDocument(path.name, source or str(path.resolve()), path=path)
        return self._ingest_pending(doc, embedder or self.embedder, IngestRun(1))

    def ingest_paths(
        self, paths: Iterable[Path], run: IngestRun | None = None
    ) -> list[IngestResult]:
        """Files and folders (recursively, supported types only); one result per file."""
        docs = [PendingDocument(p.name, str(p.resolve()), path=p) for p in expand_paths(paths)]
        return self.ingest_documents(docs, run)

    def _ingest_pending(self, doc: PendingDocument, embedder: Embedder, run: IngestRun) -> IngestResult:
        try:
            return self._ingest(doc.read(self.limits), doc.name, doc.source, embedder, run)
        except IngestError as exc:
            return IngestResult(doc.source, "failed", message=str(exc))
        except IngestCancelled:
            return IngestResult(doc.source, "cancelled", message=f"{doc.name}: cancelled; not stored")

    def _ingest(
        self, data: bytes, name: str, source: str, embedder: Embedder, run: IngestRun
    ) -> IngestResult:
        digest = hashlib.sha256(data).hexdigest()
        old = self.store.document_by_source(source)
        if old is not None and old.sha256 == digest:
            return IngestResult(source, "unchanged", old.id, old.chunks, old.pages)
        doc = extract(data, name, self.limits)
        chunks = chunk_blocks(doc.blocks)
        doc.blocks = []  # the chunks hold the text now
        vectors = self._embed(chunks, doc.title, embedder, run)
        run.check()  # the last moment a cancel leaves the store untouched
        info = self.store.replace_document(
            NewDocument(source, doc.title, digest, PurePath(name).suffix.lower().lstrip("."),
                        doc.pages, len(data), time.time()),
            [NewChunk(c.ordinal, c.text, c.section, c.page) for c in chunks],
            vectors,
        )
        status = "replaced" if old is not None else "added"
        return IngestResult(source, status, info.id, info.chunks, info.pages)

    @staticmethod
    def _embed(chunks: Sequence[Chunk], title: str, embedder: Embedder, run: IngestRun) -> np.ndarray:
        """Vectors of ``chunks``, EMBED_BATCH at a time, reporting progress; cancellable."""
        out = np.zeros((len(chunks), embedder.dim), dtype=np.float32)
        run.chunks_planned(len(chunks))
        for start in range(0, len(chunks), EMBED_BATCH):
            run.check()
            batch = chunks[start : start + EMBED_BATCH]
            out[start : start + len(batch)] = embedder.embed(
                [embed_text(title, c.section, c.text) for c in batch]
            )
            run.chunks_embedded(len(batch))
        return out

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
