"""The store interface: documents, their chunks and vectors, full-text and vector search.

Both stores (SQLite, PostgreSQL + pgvector) implement it and run the same tests. Writes
for one document happen in one transaction: a reader sees the old chunks or the new
ones, never a mix, and a failure leaves the store as it was. Methods are thread-safe
(the service runs them in worker threads).
"""

from __future__ import annotations

import re
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from sage_robot.core.errors import ConfigError

RRF_K = 60  # reciprocal-rank-fusion constant (Cormack et al. 2009)

# Words too common to help a full-text match (the vector side still sees them).
_STOPWORDS_TEXT = """
a an and are as at be been but by can could did do does for from had has have how i if in
into is it its me my of on or our so than that the their them then there these they this
to was we were what when where which who whom why will with would you your
"""
STOPWORDS = frozenset(_STOPWORDS_TEXT.split())


@dataclass(frozen=True)
class NewDocument:
    source: str  # unique key: a path, an upload's file name, "corpus/cafe.md"
    title: str
    sha256: str
    format: str  # file extension without the dot
    pages: int
    size_bytes: int
    ingested_at: float  # UNIX time (s)


@dataclass(frozen=True)
class DocumentInfo:
    id: int
    source: str
    title: str
    sha256: str
    format: str
    pages: int
    size_bytes: int
    ingested_at: float
    chunks: int

    def as_dict(self) -> dict[str, object]:
        return dict(self.__dict__)


@dataclass(frozen=True)
class NewChunk:
    ordinal: int
    text: str
    section: str
    page: int | None


@dataclass(frozen=True)
class ChunkRow:
    id: int
    document_id: int
    ordinal: int
    text: str
    section: str
    page: int | None
    title: str
    source: str


@dataclass(frozen=True)
class Hit:
    """One result of :meth:`Store.hybrid_search`."""

    chunk: ChunkRow
    score: float  # reciprocal-rank-fusion score: sum of 1 / (RRF_K + rank), rank from 1
    similarity: float  # cosine similarity to the query; 0.0 when only full text found it


def rrf_fuse(rankings: Sequence[Sequence[int]], top_k: int) -> list[tuple[int, float]]:
    """The ``top_k`` best (chunk id, score) of the rankings by reciprocal rank fusion: each
    id scores sum(1 / (RRF_K + rank)) over the rankings it is in (rank from 1); ties by id."""
    fused: dict[int, float] = {}
    for ranking in rankings:
        for rank, cid in enumerate(ranking, start=1):
            fused[cid] = fused.get(cid, 0.0) + 1.0 / (RRF_K + rank)
    return sorted(fused.items(), key=lambda item: (-item[1], item[0]))[:top_k]


def query_terms(query: str) -> list[str]:
    """Lower-case words of a query for full-text search, stopwords and duplicates removed."""
    seen: dict[str, None] = {}
    for word in re.findall(r"[a-z0-9]+", query.lower()):
        if word not in STOPWORDS and len(word) > 1:
            seen.setdefault(word, None)
    return list(seen)


class Store(ABC):
    """Where documents, chunks and vectors live."""

    dim: int

    def check_embedder(self, name: str, dim: int) -> None:
        """Refuse to mix vectors of two models: the store remembers the first one used."""
        stored = self.get_meta("embedder")
        if stored is None:
            self.set_meta("embedder", f"{name}:{dim}")
        elif stored != f"{name}:{dim}":
            raise ConfigError(
                f"the knowledge base was built with {stored.split(':')[0]}, not {name}; "
                "use that embedder or start a new store (kb.path / kb.dsn) and re-ingest"
            )

    @abstractmethod
    def get_meta(self, key: str) -> str | None: ...

    @abstractmethod
    def set_meta(self, key: str, value: str) -> None: ...

    @abstractmethod
    def document_by_source(self, source: str) -> DocumentInfo | None: ...

    @abstractmethod
    def replace_document(
        self, doc: NewDocument, chunks: Sequence[NewChunk], vectors: np.ndarray
    ) -> DocumentInfo:
        """Insert ``doc`` with its chunks, removing a document of the same source, atomically."""

    @abstractmethod
    def list_documents(self) -> list[DocumentInfo]: ...

    @abstractmethod
    def delete_document(self, document_id: int) -> bool:
        """Remove a document and its chunks; False if there was none with that id."""

    @abstractmethod
    def text_search(self, terms: Sequence[str], k: int) -> list[int]:
        """Chunk ids matching any of ``terms``, best first (BM25 / ts_rank)."""

    @abstractmethod
    def vector_search(self, vector: np.ndarray, k: int) -> list[tuple[int, float]]:
        """(chunk id, cosine similarity) of the ``k`` nearest chunks, best first."""

    @abstractmethod
    def get_chunks(self, ids: Sequence[int]) -> dict[int, ChunkRow]: ...

    def hybrid_search(
        self, vector: np.ndarray, terms: Sequence[str], n: int, top_k: int
    ) -> list[Hit]:
        """The ``n`` best of each ranking (vector, full text) fused by :func:`rrf_fuse`; the
        ``top_k`` best with their chunks. A store may do it in one query (same results)."""
        dense = self.vector_search(vector, n)
        best = rrf_fuse([[cid for cid, _ in dense], self.text_search(terms, n)], top_k)
        rows = self.get_chunks([cid for cid, _ in best])
        cosine = dict(dense)
        # A chunk deleted between the queries is left out.
        return [Hit(rows[cid], score, cosine.get(cid, 0.0)) for cid, score in best if cid in rows]

    @abstractmethod
    def count_chunks(self) -> int: ...

    @abstractmethod
    def close(self) -> None: ...

    def _check_vectors(self, chunks: Sequence[NewChunk], vectors: np.ndarray) -> np.ndarray:
        vectors = np.asarray(vectors, dtype=np.float32)
        if vectors.shape != (len(chunks), self.dim):
            raise ValueError(f"expected vectors of shape {(len(chunks), self.dim)}, got {vectors.shape}")
        return vectors
