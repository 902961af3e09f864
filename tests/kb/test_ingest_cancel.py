"""Progress and cancel of a batch ingest: in the service, through the HTTP API, and with
Ctrl-C in `sage kb ingest`. A cancelled document is not stored at all; the ones before it
are stored whole; embeddings go in bounded batches."""

from __future__ import annotations

import asyncio
import json
import signal
import threading
from collections.abc import Callable, Iterator, Sequence

import httpx
import numpy as np
import pytest
from pydantic import SecretStr

from sage_robot.cli.main import main
from sage_robot.kb import service as service_module
from sage_robot.kb.embed import Embedder
from sage_robot.kb.guard import IngestLimits
from sage_robot.kb.progress import IngestBusy, IngestRun
from sage_robot.kb.serve import create_app
from sage_robot.kb.service import EMBED_BATCH, KbService, PendingDocument
from sage_robot.kb.store.sqlite import SqliteStore

WAIT_S = 30.0  # longest wait for a step of a background ingest
PASSWORD = "operator-pw"
AUTH = {"Authorization": f"Bearer {PASSWORD}"}


def place(name: str, paragraphs: int = 6) -> bytes:
    """A Markdown document of several chunks about ``name`` (with EMBED_BATCH lowered, several
    embedding batches)."""
    body = "\n\n".join(
        f"The {name} room number {i} is open to visitors who ask at the front desk. " * 6
        for i in range(paragraphs)
    )
    return f"# {name}\n\n{body}\n".encode()


class HookEmbedder(Embedder):
    """The real (memoized) embedder; ``hook(texts)`` runs before each call; records batch sizes."""

    def __init__(self, inner: Embedder, hook: Callable[[Sequence[str]], None]) -> None:
        self.inner, self.name, self.dim, self.hook = inner, inner.name, inner.dim, hook
        self.batches: list[int] = []

    def embed(self, texts: Sequence[str]) -> np.ndarray:
        self.batches.append(len(texts))
        self.hook(texts)
        return self.inner.embed(texts)


@pytest.fixture
def small_batches(monkeypatch):
    monkeypatch.setattr(service_module, "EMBED_BATCH", 2)


def docs(*names: str) -> list[PendingDocument]:
    return [PendingDocument(f"{n}.md", f"{n}.md", data=place(n)) for n in names]


def test_progress_is_reported_and_embedding_goes_in_bounded_batches(service, embedder):
    seen = []
    service.embedder = hook = HookEmbedder(embedder, lambda texts: seen.append(service.progress()))
    assert service.progress().state == "idle"
    big = PendingDocument("big.md", "big.md", data=place("Archive", paragraphs=120))
    results = service.ingest_documents([*docs("Lobby"), big])
    assert [r.status for r in results] == ["added", "added"]
    assert results[1].chunks > EMBED_BATCH
    assert max(hook.batches) <= EMBED_BATCH
    assert {p.state for p in seen} == {"running"}
    assert {p.documents_total for p in seen} == {2}
    assert seen[0].current == "Lobby.md"
    assert seen[-1].current == "big.md"
    on_big = [p for p in seen if p.current == "big.md"]
    assert [p.chunks_done for p in on_big] == list(range(0, results[1].chunks, EMBED_BATCH))
    assert {p.chunks_total for p in on_big} == {results[1].chunks}
    assert on_big[0].documents_done == 1
    final = service.progress()
    assert (final.state, final.documents_done, final.current, final.failed) == ("done", 2, "", 0)
    assert final.finished_at >= final.started_at > 0


def test_cancel_mid_document_stores_nothing_of_it(service, embedder, small_batches):
    first = service.ingest_documents(docs("Gallery"))  # an older version of a document of the batch
    old_chunks = service.store.count_chunks()
    calls = {"n": 0}

    def cancel_in_third_document(texts: Sequence[str]) -> None:
        if any("Gallery" in t for t in texts):  # the new Gallery, its first batch
            calls["n"] += 1
            if calls["n"] == 2:  # mid-document: one batch embedded, more to come
                assert service.cancel_ingest() is True

    service.embedder = HookEmbedder(embedder, cancel_in_third_document)
    batch = [*docs("Atrium", "Lobby"), PendingDocument("Gallery.md", "Gallery.md", data=place("Gallery", 9)),
             *docs("Studio")]
    results = service.ingest_documents(batch)
    assert [r.status for r in results] == ["added", "added", "cancelled", "cancelled"]
    assert results[2].message == "Gallery.md: cancelled; not stored"
    docs_now = {str(d["source"]): d for d in service.list_documents()}
    assert set(docs_now) == {"Atrium.md", "Lobby.md", "Gallery.md"}
    gallery = docs_now["Gallery.md"]  # still the old version, whole
    assert gallery["id"] == first[0].document_id
    assert gallery["chunks"] == first[0].chunks
    assert service.store.count_chunks() == old_chunks + results[0].chunks + results[1].chunks
    progress = service.progress()
    assert (progress.state, progress.documents_done, progress.documents_total) == ("cancelled", 2, 4)
    assert service.cancel_ingest() is False  # nothing runs now


def test_one_batch_at_a_time(tmp_path, embedder):
    svc = KbService(SqliteStore(tmp_path / "kb.sqlite3", embedder.dim), embedder)
    run = svc.begin_ingest(3)
    with pytest.raises(IngestBusy, match=r"already running \(0 of 3 documents done\)"):
        svc.ingest_documents(docs("Lobby"))
    svc.ingest_documents(docs("Lobby"), run)
    assert svc.ingest_documents(docs("Atrium"))[0].status == "added"  # the first one finished
    svc.close()


# --------------------------------------------------------------------- HTTP
@pytest.fixture
def gated(tmp_path, embedder) -> Iterator[tuple[KbService, threading.Event, threading.Event]]:
    """A service whose embedder stops at the second document until ``release`` is set."""
    entered, release = threading.Event(), threading.Event()

    def gate(texts: Sequence[str]) -> None:
        if any("Lobby" in t for t in texts):
            entered.set()
            assert release.wait(WAIT_S)

    svc = KbService(SqliteStore(tmp_path / "kb.sqlite3", embedder.dim), HookEmbedder(embedder, gate))
    yield svc, entered, release
    release.set()
    svc.close()


async def test_http_progress_and_cancel(gated, small_batches):
    svc, entered, release = gated
    files = [("files", (f"{n}.md", place(n))) for n in ("Atrium", "Lobby", "Studio")]
    transport = httpx.ASGITransport(app=create_app(svc, SecretStr(PASSWORD)))
    async with httpx.AsyncClient(transport=transport, base_url="http://kb", timeout=WAIT_S) as c:
        assert (await c.get("/api/kb/ingest")).json()["state"] == "idle"
        upload = asyncio.create_task(c.post("/api/kb/documents", files=files, headers=AUTH))
        assert await asyncio.to_thread(entered.wait, WAIT_S)
        now = (await c.get("/api/kb/ingest")).json()
        assert now["state"] == "running"
        assert now["current"] == "Lobby.md"
        assert (now["documents_done"], now["documents_total"]) == (1, 3)
        assert now["chunks_total"] > 0
        assert now["chunks_done"] == 0
        busy = await c.post("/api/kb/documents", files=files[:1], headers=AUTH)
        assert busy.status_code == 409
        assert "already running (1 of 3 documents done)" in busy.json()["detail"]
        assert (await c.post("/api/kb/ingest/cancel")).status_code == 401  # writes need the login
        r = await c.post("/api/kb/ingest/cancel", headers=AUTH)
        assert r.status_code == 202
        assert r.json()["state"] == "cancelling"
        release.set()
        answer = await asyncio.wait_for(upload, WAIT_S)
        assert answer.status_code == 201
        assert [x["status"] for x in answer.json()["results"]] == ["added", "cancelled", "cancelled"]
        assert (await c.get("/api/kb/ingest")).json()["state"] == "cancelled"
        r = await c.post("/api/kb/ingest/cancel", headers=AUTH)
        assert r.status_code == 409
        assert r.json() == {"detail": "no ingest is running"}
        listed = (await c.get("/api/kb/documents")).json()["documents"]
        assert [d["source"] for d in listed] == ["Atrium.md"]
        schema = (await c.get("/openapi.json")).json()
        assert {"/api/kb/ingest", "/api/kb/ingest/cancel"} <= set(schema["paths"])


async def test_http_oversized_upload_fails_alone(tmp_path, embedder):
    svc = KbService(SqliteStore(tmp_path / "kb.sqlite3", embedder.dim), embedder)
    svc.limits = IngestLimits(max_document_bytes=10_000)
    transport = httpx.ASGITransport(app=create_app(svc, SecretStr(PASSWORD)))
    files = [("files", ("big.txt", b"word " * 5000)), ("files", ("lobby.md", place("Lobby", 1)))]
    async with httpx.AsyncClient(transport=transport, base_url="http://kb", timeout=WAIT_S) as c:
        r = await c.post("/api/kb/documents", files=files, headers=AUTH)
    svc.close()
    assert r.status_code == 201
    big, lobby = r.json()["results"]
    assert big["status"] == "failed"
    assert big["message"] == (
        "big.txt: 24 KB is larger than the 10 KB allowed per document (kb.max_document_mb)"
    )
    assert lobby["status"] == "added"


# ---------------------------------------------------------------------- CLI
def test_ctrl_c_in_kb_ingest_cancels_and_keeps_the_store_consistent(tmp_path, monkeypatch, embedder, capsys,
                                                                     small_batches):
    def ctrl_c_in_second_document(texts: Sequence[str]) -> None:
        if any("Lobby" in t for t in texts) and not pressed.is_set():
            pressed.set()
            signal.raise_signal(signal.SIGINT)  # what the terminal sends; the main thread gets it
            assert cancelled.wait(WAIT_S)  # go on once the CLI has cancelled (no race with it)

    pressed, cancelled = threading.Event(), threading.Event()
    real_cancel = IngestRun.cancel

    def cancel(run: IngestRun) -> bool:
        done = real_cancel(run)
        cancelled.set()
        return done

    monkeypatch.setattr(IngestRun, "cancel", cancel)
    hook = HookEmbedder(embedder, ctrl_c_in_second_document)
    monkeypatch.setenv("SAGE_DATA_DIR", str(tmp_path / "data"))
    monkeypatch.setattr(service_module, "make_embedder", lambda name: hook)
    folder = tmp_path / "docs"
    folder.mkdir()
    for i, name in enumerate(("Atrium", "Lobby", "Studio")):
        (folder / f"{i}-{name}.md").write_bytes(place(name))
    assert main(["kb", "ingest", str(folder), "--json"]) == 130
    out = capsys.readouterr()
    lines = [json.loads(x) for x in out.out.splitlines()]
    assert [x["status"] for x in lines] == ["added", "cancelled", "cancelled"]
    assert "cancelling; the document being read will not be stored" in out.err
    assert main(["kb", "list", "--json"]) == 0
    listed = json.loads(capsys.readouterr().out)["documents"]
    assert [d["source"].rsplit("/", 1)[-1] for d in listed] == ["0-Atrium.md"]
    assert listed[0]["chunks"] == lines[0]["chunks"]
