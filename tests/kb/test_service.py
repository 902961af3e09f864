"""Ingest through the service on both stores: formats, re-ingest, replace, delete, errors."""

from __future__ import annotations

import pytest

from sage_robot.kb.service import SearchError
from tests.kb.kb_docs import DOCX_SECTIONS, HTML, MARKDOWN, PDF_PAGES, TEXT, make_docx, make_pdf


@pytest.fixture
def folder(tmp_path):
    d = tmp_path / "docs"
    (d / "sub").mkdir(parents=True)
    (d / "library.pdf").write_bytes(make_pdf(PDF_PAGES))
    (d / "pool.docx").write_bytes(make_docx(DOCX_SECTIONS))
    (d / "sub" / "planetarium.html").write_bytes(HTML)
    (d / "greenhouse.md").write_bytes(MARKDOWN)
    (d / "bikes.txt").write_bytes(TEXT)
    (d / "corrupt.pdf").write_bytes(b"%PDF-1.4\n%\xe2\xe3\n1 0 obj <</Type /Catalog>> trailer broken")
    (d / "notes.xyz").write_bytes(b"ignored: not a supported type")
    return d


def top_source(service, question):
    return service.search(question, 3)[0].source


def test_folder_ingest_every_format_and_a_corrupt_pdf_fails_alone(service, folder):
    results = {r.source.rsplit("/", 1)[-1]: r for r in service.ingest_paths([folder])}
    assert set(results) == {
        "library.pdf",
        "pool.docx",
        "planetarium.html",
        "greenhouse.md",
        "bikes.txt",
        "corrupt.pdf",
    }
    assert results["corrupt.pdf"].status == "failed"
    assert "corrupt.pdf" in results["corrupt.pdf"].message
    assert all(r.status == "added" and r.chunks > 0 for n, r in results.items() if n != "corrupt.pdf")
    assert results["library.pdf"].pages == 2
    assert len(service.list_documents()) == 5
    # each format answers a paraphrased question about it
    assert top_source(service, "Can I borrow a notebook computer?").endswith("library.pdf")
    assert top_source(service, "How many lanes does the swimming pool have?").endswith("pool.docx")
    assert top_source(service, "When can I look through a telescope?").endswith("planetarium.html")
    assert top_source(service, "Where are orchids grown?").endswith("greenhouse.md")
    assert top_source(service, "Where can I pump up my bike tyre?").endswith("bikes.txt")
    page2 = service.search("reserve a quiet room to study", 1)[0]
    assert page2.section == "page 2"
    assert page2.title == "Library handbook"


def test_unchanged_reingest_is_a_no_op(service, folder):
    first = service.ingest_paths([folder / "pool.docx", folder / "greenhouse.md"])
    docs_before = service.list_documents()
    chunks_before = service.store.count_chunks()
    again = service.ingest_paths([folder / "pool.docx", folder / "greenhouse.md"])
    assert [r.status for r in again] == ["unchanged", "unchanged"]
    assert [r.document_id for r in again] == [r.document_id for r in first]
    assert service.list_documents() == docs_before  # same ingest times: nothing was rewritten
    assert service.store.count_chunks() == chunks_before


def test_changed_file_replaces_its_chunks(service, tmp_path):
    path = tmp_path / "hours.md"
    path.write_text("# Gym\n\nThe gym opens at six in the morning.\n")
    first = service.ingest_file(path)
    path.write_text("# Gym\n\nThe climbing wall is open on Sunday afternoons.\n")
    second = service.ingest_file(path)
    assert (first.status, second.status) == ("added", "replaced")
    assert second.document_id == first.document_id
    assert len(service.list_documents()) == 1
    texts = [p.text for p in service.search("gym opening time climbing wall", 5)]
    assert texts == ["The climbing wall is open on Sunday afternoons."]


def test_delete_by_document(service, folder):
    results = service.ingest_paths([folder / "bikes.txt", folder / "greenhouse.md"])
    assert service.delete_document(results[0].document_id) is True
    assert all(not p.source.endswith("bikes.txt") for p in service.search("bicycle repair", 5))
    assert service.delete_document(results[0].document_id) is False


def test_missing_file_is_a_failed_result(service, tmp_path):
    [result] = service.ingest_paths([tmp_path / "nope.md"])
    assert result.status == "failed"
    assert "cannot read" in result.message


@pytest.mark.parametrize(
    ("query", "top_k", "message"),
    [
        ("   ", 5, "the query is empty"),
        ("x", 0, "top_k must be between 1 and 50"),
        ("x", 51, "top_k must be between"),
        ("x" * 2001, 5, "longer than 2000"),
    ],
)
def test_bad_searches_name_the_problem(service, query, top_k, message):
    with pytest.raises(SearchError, match=message):
        service.search(query, top_k)


def test_search_on_an_empty_store_returns_nothing(service):
    assert service.search("anything at all", 5) == []


def test_corpus_first_run_then_refresh_without_resurrecting_deleted(service, tmp_path):
    corpus = tmp_path / "corpus"
    (corpus / "places").mkdir(parents=True)
    (corpus / "building.md").write_text("# Building\n\nOpen from seven.\n")
    (corpus / "places" / "cafe.md").write_text("# Cafe\n\nCoffee and bagels.\n")
    first = service.ensure_corpus(corpus)
    assert sorted((r.source, r.status) for r in first) == [
        ("corpus/building.md", "added"),
        ("corpus/places/cafe.md", "added"),
    ]
    cafe = next(r for r in first if r.source.endswith("cafe.md"))
    service.delete_document(cafe.document_id)  # an operator removed it
    (corpus / "building.md").write_text("# Building\n\nOpen from eight.\n")  # a new release edits it
    again = service.ensure_corpus(corpus)
    assert [(r.source, r.status) for r in again] == [("corpus/building.md", "replaced")]
    assert [d["source"] for d in service.list_documents()] == ["corpus/building.md"]
