"""The HTTP API: search, upload -> search, list, delete, e-mail, login, errors, OpenAPI.

Most requests go through httpx's ASGI transport; one test runs a real uvicorn server on
loopback; the e-mail endpoint talks to a real SMTP server.
"""

from __future__ import annotations

import base64
import threading
from collections.abc import Iterator

import httpx
import pytest
import uvicorn
from pydantic import SecretStr

from sage_robot.core.config.areas import EmailSettings
from sage_robot.kb.serve import create_app
from sage_robot.kb.service import KbService
from sage_robot.kb.store.sqlite import SqliteStore
from tests.kb.kb_docs import DOCX_SECTIONS, MARKDOWN, make_docx, make_pdf
from tests.kb.kb_smtp import free_port, smtp_server

PASSWORD = "operator-pw"
BASIC = {"Authorization": "Basic " + base64.b64encode(f"op:{PASSWORD}".encode()).decode()}
BEARER = {"Authorization": f"Bearer {PASSWORD}"}
TIMEOUT_S = 30.0


@pytest.fixture
def kb(tmp_path, embedder) -> Iterator[KbService]:
    service = KbService(SqliteStore(tmp_path / "kb.sqlite3", embedder.dim), embedder)
    yield service
    service.close()


def client(app) -> httpx.AsyncClient:
    return httpx.AsyncClient(transport=httpx.ASGITransport(app=app), base_url="http://kb", timeout=TIMEOUT_S)


async def upload(c: httpx.AsyncClient, files: list[tuple[str, bytes]], headers=BASIC) -> httpx.Response:
    return await c.post("/api/kb/documents", files=[("files", f) for f in files], headers=headers)


async def test_upload_then_search_then_delete(kb):
    async with client(create_app(kb, SecretStr(PASSWORD))) as c:
        r = await upload(c, [("pool.docx", make_docx(DOCX_SECTIONS)), ("greenhouse.md", MARKDOWN)])
        assert r.status_code == 201, r.text
        assert [x["status"] for x in r.json()["results"]] == ["added", "added"]
        r = await c.post("/api/kb/search", json={"query": "how many swimming lanes are there?", "top_k": 2})
        assert r.status_code == 200
        answer = r.json()
        assert answer["query"] == "how many swimming lanes are there?"
        assert len(answer["results"]) == 2
        best = answer["results"][0]
        assert best["source"] == "pool.docx"
        assert "eight lanes" in best["content"]
        docs = (await c.get("/api/kb/documents")).json()["documents"]
        assert {d["source"] for d in docs} == {"pool.docx", "greenhouse.md"}
        pool = next(d for d in docs if d["source"] == "pool.docx")
        r = await c.delete(f"/api/kb/documents/{pool['id']}", headers=BEARER)
        assert r.status_code == 204
        r = await c.delete(f"/api/kb/documents/{pool['id']}", headers=BEARER)
        assert r.status_code == 404
        assert r.json() == {"detail": f"no document with id {pool['id']}"}
        r = await c.post("/api/kb/search", json={"query": "swimming lanes"})
        assert all(x["source"] != "pool.docx" for x in r.json()["results"])


async def test_reupload_unchanged_is_a_no_op_and_a_corrupt_file_fails_alone(kb):
    async with client(create_app(kb, SecretStr(PASSWORD))) as c:
        await upload(c, [("greenhouse.md", MARKDOWN)])
        r = await upload(c, [("greenhouse.md", MARKDOWN), ("broken.pdf", b"%PDF-1.4 garbage")])
        assert r.status_code == 201
        assert [x["status"] for x in r.json()["results"]] == ["unchanged", "failed"]
        assert "broken.pdf" in r.json()["results"][1]["message"]
        r = await upload(c, [("broken.pdf", b"%PDF-1.4 garbage")])
        assert r.status_code == 422
        assert "broken.pdf" in r.json()["detail"]
        r = await upload(c, [("photo.png", b"\x89PNG")])
        assert r.status_code == 422
        assert "unsupported file type '.png'" in r.json()["detail"]


async def test_writes_need_the_operator_login(kb):
    async with client(create_app(kb, SecretStr(PASSWORD))) as c:
        for headers in ({}, {"Authorization": "Bearer nope"}, {"Authorization": "Basic !!!"}):
            r = await upload(c, [("greenhouse.md", MARKDOWN)], headers=headers)
            assert r.status_code == 401
            assert r.json() == {"detail": "operator login required"}
            assert r.headers["www-authenticate"].startswith("Basic")
        assert (await c.delete("/api/kb/documents/1")).status_code == 401
        r = await c.post("/api/kb/send-emails", json={"subject": "s", "body": "b"})
        assert r.status_code == 401
        assert (await c.get("/api/kb/documents")).json() == {"documents": []}  # nothing was written
    async with client(create_app(kb, None)) as c:  # no password configured: writes disabled
        r = await upload(c, [("greenhouse.md", MARKDOWN)], headers=BASIC)
        assert r.status_code == 403
        assert "SAGE_OPERATOR_PASSWORD" in r.json()["detail"]


async def test_bad_requests_get_json_4xx(kb):
    async with client(create_app(kb, SecretStr(PASSWORD))) as c:
        r = await c.post("/api/kb/search", json={"query": "", "top_k": 5})
        assert r.status_code == 422
        assert r.json()["detail"][0]["loc"] == ["body", "query"]
        r = await c.post("/api/kb/search", json={"query": "x", "top_k": 500})
        assert r.status_code == 422
        assert r.json()["detail"][0]["loc"] == ["body", "top_k"]
        r = await c.post("/api/kb/search", content=b"not json", headers={"Content-Type": "application/json"})
        assert r.status_code == 422
        assert "detail" in r.json()
        r = await c.post("/api/kb/search", json={"query": "   "})
        assert r.status_code == 422
        assert r.json() == {"detail": "the query is empty"}
        r = await c.delete("/api/kb/documents/abc", headers=BASIC)
        assert r.status_code == 422


async def test_send_emails_through_a_real_smtp_server(kb):
    with smtp_server() as (port, inbox):
        email = EmailSettings(
            smtp_host="127.0.0.1", smtp_port=port, starttls=False, recipients=("ops@x.test",)
        )
        async with client(create_app(kb, SecretStr(PASSWORD), email)) as c:
            body = {"subject": "Battery low", "body": "SAGE is at 20 %."}
            r = await c.post("/api/kb/send-emails", json=body, headers=BASIC)
            assert r.status_code == 200
            assert r.json()["ok"] is True
            r = await c.post(
                "/api/kb/send-emails", json={**body, "recipients": ["not-an-address"]}, headers=BASIC
            )
            assert r.status_code == 422
            assert "not an e-mail address" in r.json()["detail"]
    assert [m["Subject"] for m in inbox.messages] == ["Battery low"]
    async with client(create_app(kb, SecretStr(PASSWORD), None)) as c:
        r = await c.post("/api/kb/send-emails", json={"subject": "s"}, headers=BASIC)
        assert r.status_code == 503
        assert "not configured" in r.json()["detail"]


def test_openapi_schema_is_valid(kb):
    from openapi_spec_validator import validate

    schema = create_app(kb, SecretStr(PASSWORD)).openapi()
    validate(schema)
    paths = schema["paths"]
    assert {
        "/api/kb/search",
        "/api/kb/documents",
        "/api/kb/documents/{document_id}",
        "/api/kb/send-emails",
    } <= set(paths)
    assert set(paths["/api/kb/documents"]) == {"get", "post"}
    assert "/kb/admin" not in paths


async def test_admin_page_is_served(kb):
    async with client(create_app(kb, SecretStr(PASSWORD))) as c:
        page = await c.get("/kb/admin")
        script = await c.get("/kb/admin/admin.js")
    assert page.status_code == 200
    assert "text/html" in page.headers["content-type"]
    assert '<script type="module" src="/kb/admin/admin.js">' in page.text
    assert script.status_code == 200
    assert "javascript" in script.headers["content-type"]
    assert "/api/kb/documents" in script.text


@pytest.fixture
def real_server(kb) -> Iterator[str]:
    port = free_port()
    server = uvicorn.Server(
        uvicorn.Config(
            create_app(kb, SecretStr(PASSWORD)),
            host="127.0.0.1",
            port=port,
            log_level="warning",
            lifespan="off",
        )
    )
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    for _ in range(200):  # up to 10 s
        if server.started:
            break
        threading.Event().wait(0.05)
    assert server.started, "uvicorn did not start"
    yield f"http://127.0.0.1:{port}"
    server.should_exit = True
    thread.join(10)


async def test_upload_and_search_over_a_real_http_server(real_server):
    pdf = make_pdf(["The library lends laptops for up to three days to any student with an ID card."])
    async with httpx.AsyncClient(base_url=real_server, timeout=TIMEOUT_S) as c:
        r = await c.post("/api/kb/documents", files=[("files", ("library.pdf", pdf))], headers=BASIC)
        assert r.status_code == 201
        assert r.json()["results"][0]["status"] == "added"
        r = await c.post("/api/kb/search", json={"query": "can I borrow a notebook computer", "top_k": 1})
        [hit] = r.json()["results"]
        assert hit["source"] == "library.pdf"
        assert hit["section"] == "page 1"
        r = await c.post("/api/kb/documents", files=[("files", ("x.md", b"# x"))])
        assert r.status_code == 401
