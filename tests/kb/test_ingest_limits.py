"""Bounded ingest: size limits, zip bombs refused from the zip directory, streaming text with
a character cap, binary content anywhere in a text file, and bad documents that fail alone.

Memory is measured with tracemalloc (Python allocations: file bytes, decoded text, blocks,
chunks); the bounds are stated next to each assertion.
"""

from __future__ import annotations

import io
import re
import tracemalloc
import zipfile
from collections.abc import Callable, Iterator
from typing import TypeVar

import pytest

from sage_robot.core.config.areas import KbSettings
from sage_robot.kb import service as service_module
from sage_robot.kb.extract import MAX_BLOCK_CHARS, READERS, extract
from sage_robot.kb.guard import MAX_LINE_CHARS, MB, IngestError, IngestLimits, iter_lines
from sage_robot.kb.service import KbService
from sage_robot.kb.store.sqlite import SqliteStore
from tests.kb.kb_docs import DOCX_SECTIONS, MARKDOWN, TEXT, make_docx
from tests.kb.kb_hostile import make_bomb_docx, make_docx_with, text_with

T = TypeVar("T")


@pytest.fixture(scope="module")
def bomb() -> bytes:
    return make_bomb_docx(300)  # 300 MB of text in a few hundred KB


@pytest.fixture
def sqlite_service(tmp_path, embedder) -> Iterator[KbService]:
    svc = KbService(SqliteStore(tmp_path / "kb.sqlite3", embedder.dim), embedder)
    yield svc
    svc.close()


def peak_bytes(fn: Callable[[], T]) -> tuple[T, int]:
    """``fn()`` and the peak of Python memory allocated while it ran (tracemalloc)."""
    tracemalloc.start()
    try:
        out = fn()
        return out, tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def sources(service: KbService) -> set[str]:
    return {str(d["source"]) for d in service.list_documents()}


# ------------------------------------------------------------------ zip bombs
def test_the_bomb_is_a_valid_docx_of_a_few_hundred_kb(bomb):
    info = zipfile.ZipFile(io.BytesIO(bomb)).getinfo("word/document.xml")
    assert len(bomb) < 600_000
    assert info.file_size > 300 * MB


def test_zip_bomb_docx_is_refused_before_anything_is_inflated(service, bomb, monkeypatch):
    def no_inflating(*args, **kwargs):
        raise AssertionError("a zip member was opened")

    with monkeypatch.context() as m:
        m.setattr(zipfile.ZipFile, "open", no_inflating)
        result, peak = peak_bytes(lambda: service.ingest_bytes(bomb, "bomb.docx"))
    assert result.status == "failed"
    assert result.message.startswith("bomb.docx: word/document.xml would unpack")
    assert "kb.max_zip_ratio" in result.message
    assert "zip bomb" in result.message
    assert peak < 5 * MB  # the file is 0.3 MB; inflating it would take 300 MB
    assert service.list_documents() == []
    assert service.store.count_chunks() == 0


def test_zip_limits_each_name_the_document_and_the_setting(bomb):
    lenient_ratio = IngestLimits(max_zip_ratio=10_000)
    with pytest.raises(IngestError, match=r"^bomb\.docx: the DOCX package would unpack to 30\d MB, more "
                                          r"than the 50 MB allowed \(kb\.max_inflated_mb\)"):
        extract(bomb, "bomb.docx", lenient_ratio)
    crowded = make_docx_with(members=40)
    too_many = r"^crowded\.docx: \d+ files inside .* at most 20 .*kb\.max_zip_members"
    with pytest.raises(IngestError, match=too_many):
        extract(crowded, "crowded.docx", IngestLimits(max_zip_members=20))
    assert extract(crowded, "crowded.docx").title == "Swimming pool guide"  # the default allows it
    bz = make_docx_with(method=zipfile.ZIP_BZIP2)
    with pytest.raises(IngestError, match=r"^bz\.docx: .* compression method 12; .*only stored or deflate"):
        extract(bz, "bz.docx")
    with pytest.raises(IngestError, match=r"^fake\.docx: not a readable DOCX file \(not a zip package\)"):
        extract(b"PK\x03\x04" + b"\x00" * 100, "fake.docx")


# ------------------------------------------------------------ size and text
def test_oversized_file_is_refused_from_its_size_without_reading_it(sqlite_service, tmp_path, monkeypatch):
    settings = KbSettings(path=str(tmp_path / "kb.sqlite3"), max_document_mb=0.5)
    sqlite_service.limits = IngestLimits.from_settings(settings)
    assert sqlite_service.limits.max_document_bytes == MB // 2
    big = tmp_path / "big.txt"
    big.write_bytes(text_with(b"x", 0, size=2 * MB))
    result, peak = peak_bytes(lambda: sqlite_service.ingest_file(big))
    assert result.status == "failed"
    assert result.message == (
        "big.txt: 2.0 MB is larger than the 0.5 MB allowed per document (kb.max_document_mb)"
    )
    assert peak < 200_000  # stat() only: the 2 MB were never read
    # the same limit holds for bytes given directly
    assert "larger than the 0.5 MB" in sqlite_service.ingest_bytes(big.read_bytes(), "big.txt").message


def test_text_over_the_character_cap_is_refused_in_bounded_memory(sqlite_service, tmp_path):
    sqlite_service.limits = IngestLimits(max_chars=50_000)
    size = 8 * MB
    path = tmp_path / "long.txt"
    path.write_bytes(text_with(b"x", 0, size=size))
    result, peak = peak_bytes(lambda: sqlite_service.ingest_file(path))
    assert result.status == "failed"
    assert result.message == (
        "long.txt: more than 50,000 characters of text; split the document or raise kb.max_chars"
    )
    # The file's bytes, one decoded slice (256 KB) and the blocks below the cap. Decoding the
    # whole file and splitting it (the old way) peaked at 13x the file size (106 MB here).
    assert peak < size + 2 * MB, peak
    assert sqlite_service.list_documents() == []


def test_text_is_read_line_by_line_whatever_the_line_length():
    words = " ".join(f"word{i}" for i in range(60_000))  # 530 KB on one line
    data = f"{words}\n\nSecond paragraph.\r\nSame paragraph.\n".encode()
    lines = list(iter_lines(data, "one-line.txt"))
    assert max(len(x) for x in lines) <= MAX_LINE_CHARS
    doc = extract(data, "one-line.txt")
    assert all(len(b.text) <= MAX_BLOCK_CHARS + MAX_LINE_CHARS for b in doc.blocks)
    # cut at spaces: no word is broken, nothing is lost
    assert " ".join(b.text for b in doc.blocks[:-1]) == words
    assert doc.blocks[-1].text == "Second paragraph. Same paragraph."


@pytest.mark.parametrize("slice_bytes", [7, 64, 1 << 20])
def test_lines_do_not_depend_on_the_decode_slice(slice_bytes, monkeypatch):
    text = "Café\r\nnaïve line\rold mac\n\n\u2028x\r\n" * 20 + "last without end"
    data = text.encode()
    monkeypatch.setattr("sage_robot.kb.guard.DECODE_SLICE_BYTES", slice_bytes)
    assert list(iter_lines(data, "a.txt")) == text.splitlines()


# ------------------------------------------------------------------ binary
@pytest.mark.parametrize(
    ("data", "why"),
    [
        (text_with(b"\x00", 100_000), r"a NUL byte at offset 100,000"),
        (text_with(b"\x81\x8d", 150_000), r"not UTF-8 or Windows-1252 text at offset 150,000"),
        (text_with(b"\x01\x02\x03\x04" * 1000, 120_000), r"4,000 control characters in 200,000"),
    ],
    ids=["nul", "not-text", "controls"],
)
def test_binary_content_deep_in_a_text_file_is_refused(sqlite_service, data, why):
    result = sqlite_service.ingest_bytes(data, "notes.txt")
    assert result.status == "failed"
    assert re.fullmatch(rf"notes\.txt: looks like a binary file, not text \({why}\)", result.message)
    assert sqlite_service.list_documents() == []


def test_legacy_and_utf16_text_are_still_text():
    windows = "\u201cQuoted\u201d caf\u00e9 hours.".encode("cp1252")
    assert extract(windows, "w.txt").blocks[0].text == "\u201cQuoted\u201d caf\u00e9 hours."
    utf16 = "Opening hours: nine to five.".encode("utf-16")
    assert extract(utf16, "u.txt").blocks[0].text == "Opening hours: nine to five."


# ------------------------------------------------- bad documents fail alone
def test_bad_documents_fail_alone_and_leave_the_store_untouched(service, tmp_path, bomb):
    folder = tmp_path / "batch"
    folder.mkdir()
    (folder / "greenhouse.md").write_bytes(MARKDOWN)
    (folder / "bikes.txt").write_bytes(TEXT)
    first = {r.source.rsplit("/", 1)[-1]: r for r in service.ingest_paths([folder])}
    assert {r.status for r in first.values()} == {"added"}
    before = (service.list_documents(), service.store.count_chunks())

    (folder / "bikes.txt").write_bytes(text_with(b"\x00", 100_000))  # a bad new version
    (folder / "bomb.docx").write_bytes(bomb)
    (folder / "broken.pdf").write_bytes(b"%PDF-1.4 garbage")
    (folder / "pool.docx").write_bytes(make_docx(DOCX_SECTIONS))
    results = {r.source.rsplit("/", 1)[-1]: r for r in service.ingest_paths([folder])}
    assert {n: r.status for n, r in results.items()} == {
        "bikes.txt": "failed", "bomb.docx": "failed", "broken.pdf": "failed",
        "greenhouse.md": "unchanged", "pool.docx": "added",
    }
    for name in ("bikes.txt", "bomb.docx", "broken.pdf"):
        assert results[name].message.startswith(f"{name}: "), results[name].message
    docs = {str(d["source"]).rsplit("/", 1)[-1]: d for d in service.list_documents()}
    assert set(docs) == {"greenhouse.md", "bikes.txt", "pool.docx"}
    # the failed new version of bikes.txt left the old one as it was
    assert [d for d in before[0] if str(d["source"]).endswith("bikes.txt")] == [docs["bikes.txt"]]
    assert service.store.count_chunks() == before[1] + results["pool.docx"].chunks
    assert service.search("Where can I pump up my bike tyre?", 1)[0].source.endswith("bikes.txt")


def test_a_parser_crash_is_a_failed_document(sqlite_service, monkeypatch):
    def crash(data, name, limits):
        raise RecursionError("maximum recursion depth exceeded")

    monkeypatch.setitem(READERS, ".md", crash)
    result = sqlite_service.ingest_bytes(MARKDOWN, "deep.md")
    assert result.status == "failed"
    assert result.message == "deep.md: could not be read (RecursionError: maximum recursion depth exceeded)"


def test_limits_come_from_the_settings(tmp_path, embedder, monkeypatch):
    monkeypatch.setattr(service_module, "make_embedder", lambda name: embedder)
    settings = KbSettings(path=str(tmp_path / "kb.sqlite3"), max_document_mb=1.5, max_inflated_mb=8,
                          max_zip_members=30, max_zip_ratio=50, max_chars=1000)
    svc = KbService.from_settings(settings)
    try:
        assert svc.limits == IngestLimits(int(1.5 * MB), 8 * MB, 30, 50.0, 1000)
        assert "more than 1,000 characters" in svc.ingest_bytes(b"word " * 300, "a.txt").message
    finally:
        svc.close()
    with pytest.raises(ValueError, match="max_document_mb"):
        KbSettings(max_document_mb=0)
