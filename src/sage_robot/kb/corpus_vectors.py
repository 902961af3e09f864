"""Make ``data/kb/vectors.npz``: the vectors of the shipped corpus's chunks.

Run after editing the corpus (a test fails with this command when the file is stale):

    python -m sage_robot.kb.corpus_vectors
"""

from __future__ import annotations

import tempfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from sage_robot.kb.embed import Embedder, make_embedder, text_key
from sage_robot.kb.service import CORPUS_VECTORS, KbService
from sage_robot.kb.store.sqlite import SqliteStore


class _Recorder(Embedder):
    def __init__(self, inner: Embedder) -> None:
        self.inner, self.name, self.dim = inner, inner.name, inner.dim
        self.seen: dict[str, np.ndarray] = {}

    def embed(self, texts: Sequence[str]) -> np.ndarray:
        vectors = self.inner.embed(texts)
        self.seen.update((text_key(t), v) for t, v in zip(texts, vectors, strict=True))
        return vectors


def build(path: Path = CORPUS_VECTORS, embedder_name: str = "all-MiniLM-L6-v2") -> int:
    """Embed every chunk of the corpus afresh and write the table; returns the chunk count."""
    recorder = _Recorder(make_embedder(embedder_name))
    with tempfile.TemporaryDirectory() as tmp:
        service = KbService(SqliteStore(Path(tmp) / "kb.sqlite3", recorder.dim), recorder)
        for source, file in service.corpus_files().items():
            result = service.ingest_file(file, source, recorder)
            if not result.ok:
                raise SystemExit(result.message)
        service.close()
    keys = sorted(recorder.seen)
    np.savez_compressed(
        path,
        embedder=np.array(embedder_name),
        keys=np.array(keys),
        vectors=np.stack([recorder.seen[k] for k in keys]).astype(np.float32),
    )
    return len(keys)


if __name__ == "__main__":
    print(f"{CORPUS_VECTORS}: {build()} vectors")
