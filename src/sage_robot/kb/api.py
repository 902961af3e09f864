"""HTTP API of the knowledge base (FastAPI router), mounted by the web server or by
``sage kb serve``.

- ``POST /api/kb/search`` ``{"query", "top_k"}`` -> ``{"query", "results": [{"content",
  "source", "title", "section", "score", "similarity", "document_id"}]}`` (seed-compatible)
- ``GET /api/kb/documents``; ``POST /api/kb/documents`` (multipart ``files``: upload and
  ingest, one batch at a time); ``DELETE /api/kb/documents/{id}``
- ``GET /api/kb/ingest`` (progress of the running or latest upload batch);
  ``POST /api/kb/ingest/cancel``
- ``POST /api/kb/send-emails`` ``{"subject", "body", "recipients"?}`` (SMTP from the profile)
- ``GET /kb/admin``: the admin page (upload, list, delete, try a question)

Writes depend on ``require_operator``, a FastAPI dependency the caller passes in (the web
server's login; ``sage kb serve`` its own password check). Errors are JSON ``{"detail"}``.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from pathlib import Path, PurePath
from typing import Any, Literal

from fastapi import APIRouter, Depends, File, HTTPException, UploadFile
from fastapi.responses import FileResponse, Response
from pydantic import BaseModel, Field

from sage_robot.core.config.areas import EmailSettings
from sage_robot.kb.mail import send_mail_async
from sage_robot.kb.progress import IngestBusy
from sage_robot.kb.service import (
    MAX_QUERY_CHARS,
    MAX_TOP_K,
    KbService,
    PendingDocument,
    SearchError,
    passages_as_answer,
)

ADMIN_DIR = Path(__file__).resolve().parents[1] / "data" / "kb" / "admin"

ServiceSource = KbService | Callable[[], KbService | None]


class SearchBody(BaseModel):
    query: str = Field(..., min_length=1, max_length=MAX_QUERY_CHARS, description="The question.")
    top_k: int = Field(5, ge=1, le=MAX_TOP_K, description="Passages to return.")


class SearchResult(BaseModel):
    content: str
    source: str
    title: str
    section: str
    score: float = Field(description="Reciprocal-rank-fusion score; higher is better.")
    similarity: float = Field(description="Cosine similarity of query and passage (-1..1).")
    document_id: int


class SearchAnswer(BaseModel):
    query: str
    results: list[SearchResult]


class DocumentOut(BaseModel):
    id: int
    source: str
    title: str
    sha256: str
    format: str
    pages: int
    size_bytes: int
    ingested_at: float = Field(description="UNIX time (s).")
    chunks: int


class DocumentList(BaseModel):
    documents: list[DocumentOut]


class IngestOut(BaseModel):
    source: str
    status: str = Field(description="added, replaced, unchanged, failed or cancelled (not stored)")
    document_id: int
    chunks: int
    pages: int
    message: str


class UploadAnswer(BaseModel):
    results: list[IngestOut]


class ProgressOut(BaseModel):
    state: Literal["idle", "running", "cancelling", "done", "cancelled"]
    documents_total: int
    documents_done: int
    current: str = Field(description="Name of the document being ingested.")
    chunks_total: int = Field(description="Passages of the current document.")
    chunks_done: int = Field(description="Passages of the current document embedded so far.")
    failed: int = Field(description="Documents of the batch that failed so far.")
    started_at: float = Field(description="UNIX time (s); 0 when idle.")
    finished_at: float = Field(description="UNIX time (s); 0 while running.")


class EmailBody(BaseModel):
    subject: str = Field(..., min_length=1, max_length=200)
    body: str = Field("", max_length=100_000, description="Plain-text message.")
    recipients: list[str] | None = Field(None, description="Default: the profile's list.")


class EmailAnswer(BaseModel):
    ok: bool
    recipients: list[str]
    attempts: int
    error: str


def make_router(
    service: ServiceSource,
    require_operator: Callable[..., Any],
    email: EmailSettings | None = None,
    secrets_file: str | None = None,
) -> APIRouter:
    """The KB's routes. ``service`` is a :class:`KbService` or a function returning it (None
    while it starts: 503). ``email`` configures ``/api/kb/send-emails`` (None: 503)."""
    router = APIRouter()
    write = [Depends(require_operator)]
    svc = _service_getter(service)
    _add_search_route(router, svc)
    _add_document_routes(router, svc, write)
    _add_email_route(router, write, email, secrets_file)
    _add_admin_routes(router)
    return router


def _service_getter(service: ServiceSource) -> Callable[[], KbService]:
    """The function the routes call for the service: 503 while there is none yet."""

    def svc() -> KbService:
        found = service() if callable(service) and not isinstance(service, KbService) else service
        if found is None:
            raise HTTPException(503, "the knowledge base is starting; try again in a moment")
        return found

    return svc


# ---------------------------------------------------------------- route registration
# The handlers are thin: FastAPI reads their signatures (body, files, path parameters);
# the work is in the module-level functions below them.


def _add_search_route(router: APIRouter, svc: Callable[[], KbService]) -> None:
    @router.post("/api/kb/search", response_model=SearchAnswer, tags=["kb"])
    async def search(body: SearchBody) -> dict[str, Any]:
        return await _search(svc(), body)


def _add_document_routes(router: APIRouter, svc: Callable[[], KbService], write: list[Any]) -> None:
    """Documents and their ingest: list, upload, progress, cancel, delete."""

    @router.get("/api/kb/documents", response_model=DocumentList, tags=["kb"])
    async def list_documents() -> dict[str, Any]:
        return {"documents": await asyncio.to_thread(svc().list_documents)}

    @router.post("/api/kb/documents", response_model=UploadAnswer, status_code=201,
                 dependencies=write, tags=["kb"], responses={409: {"description": "an ingest runs"}})
    async def upload(
        files: list[UploadFile] = File(..., description="Documents to ingest"),
    ) -> dict[str, Any]:
        return await _upload(svc(), files)

    @router.get("/api/kb/ingest", response_model=ProgressOut, tags=["kb"])
    async def ingest_progress() -> dict[str, Any]:
        return svc().progress().as_dict()

    @router.post("/api/kb/ingest/cancel", response_model=ProgressOut, status_code=202,
                 dependencies=write, tags=["kb"], responses={409: {"description": "none runs"}})
    async def ingest_cancel() -> dict[str, Any]:
        return _cancel_ingest(svc())

    @router.delete("/api/kb/documents/{document_id}", status_code=204, dependencies=write,
                   tags=["kb"], response_class=Response)
    async def delete(document_id: int) -> Response:
        return await _delete_document(svc(), document_id)


def _add_email_route(
    router: APIRouter, write: list[Any], email: EmailSettings | None, secrets_file: str | None
) -> None:
    @router.post("/api/kb/send-emails", response_model=EmailAnswer, dependencies=write, tags=["kb"])
    async def send_emails(body: EmailBody) -> Any:
        return await _send_emails(email, secrets_file, body)


def _add_admin_routes(router: APIRouter) -> None:
    @router.get("/kb/admin", include_in_schema=False)
    async def admin_page() -> FileResponse:
        return FileResponse(ADMIN_DIR / "index.html", media_type="text/html")

    @router.get("/kb/admin/admin.js", include_in_schema=False)
    async def admin_script() -> FileResponse:
        return FileResponse(ADMIN_DIR / "admin.js", media_type="text/javascript")


# ---------------------------------------------------------------- what the routes do


async def _search(kb: KbService, body: SearchBody) -> dict[str, Any]:
    try:
        passages = await asyncio.to_thread(kb.search, body.query, body.top_k)
    except SearchError as exc:
        raise HTTPException(422, str(exc)) from None
    return passages_as_answer(body.query, passages)


def _pending_documents(files: list[UploadFile]) -> list[PendingDocument]:
    docs = []
    for upload_file in files:
        name = PurePath(upload_file.filename or "").name
        if not name:
            raise HTTPException(422, "an uploaded file has no name")
        # Read in the worker when its turn comes, at most the size limit (kb.max_document_mb).
        docs.append(PendingDocument(name, name, stream=upload_file.file))
    return docs


async def _upload(kb: KbService, files: list[UploadFile]) -> dict[str, Any]:
    docs = _pending_documents(files)
    try:
        run = kb.begin_ingest(len(docs))
    except IngestBusy as exc:
        raise HTTPException(409, str(exc)) from None
    try:
        done = await asyncio.to_thread(kb.ingest_documents, docs, run)
    except asyncio.CancelledError:  # the server stops: the worker stops at its next check
        run.cancel()
        raise
    results = [r.as_dict() for r in done]
    if all(r["status"] == "failed" for r in results):
        raise HTTPException(422, "; ".join(str(r["message"]) for r in results))
    return {"results": results}


def _cancel_ingest(kb: KbService) -> dict[str, Any]:
    if not kb.cancel_ingest():
        raise HTTPException(409, "no ingest is running")
    return kb.progress().as_dict()


async def _delete_document(kb: KbService, document_id: int) -> Response:
    if not await asyncio.to_thread(kb.delete_document, document_id):
        raise HTTPException(404, f"no document with id {document_id}")
    return Response(status_code=204)


async def _send_emails(email: EmailSettings | None, secrets_file: str | None, body: EmailBody) -> Any:
    if email is None or not email.smtp_host:
        raise HTTPException(503, "e-mail is not configured (email.smtp_host in the profile)")
    result = await send_mail_async(email, body.subject, body.body, body.recipients, secrets_file)
    if not result.ok:  # nothing tried = the request was wrong; else the server failed
        raise HTTPException(422 if result.attempts == 0 else 502, result.error)
    return result.as_dict()
