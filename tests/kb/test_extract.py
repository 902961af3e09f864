"""Text out of each format, with titles and sections; broken files fail with a clear error."""

from __future__ import annotations

import itertools

import pytest

from sage_robot.kb.chunk import chunk_blocks
from sage_robot.kb.extract import IngestError, extract
from tests.kb.kb_docs import DOCX_SECTIONS, HTML, MARKDOWN, PDF_PAGES, TEXT, make_docx, make_pdf


def test_markdown_keeps_heading_paths():
    doc = extract(MARKDOWN, "greenhouse.md")
    assert doc.title == "Greenhouse"
    assert [b.section for b in doc.blocks] == ["Greenhouse > Plants", "Greenhouse > Visiting"]
    assert "orchids" in doc.blocks[0].text


def test_plain_text_paragraphs():
    doc = extract(TEXT, "bikes.txt")
    assert doc.title == "bikes"
    assert len(doc.blocks) == 3
    assert doc.blocks[1].text.startswith("A free bicycle repair stand")


def test_pdf_pages_become_sections():
    doc = extract(make_pdf(PDF_PAGES), "library.pdf")
    assert doc.title == "Library handbook"
    assert doc.pages == 2
    assert {b.page for b in doc.blocks} == {1, 2}
    assert any("laptops" in b.text and b.section == "page 1" for b in doc.blocks)
    assert any("Silent study rooms" in b.text and b.section == "page 2" for b in doc.blocks)


def test_docx_headings_become_sections():
    doc = extract(make_docx(DOCX_SECTIONS), "pool.docx")
    assert doc.title == "Swimming pool guide"
    assert [b.section for b in doc.blocks] == ["Lanes", "Lifeguards"]
    assert "eight lanes" in doc.blocks[0].text


def test_html_main_text_without_boilerplate():
    doc = extract(HTML, "planetarium.html")
    assert doc.title == "Planetarium shows"
    text = " ".join(b.text for b in doc.blocks)
    assert "Saturn's rings" in text
    assert "Friday evening" in text
    assert "Cookie settings" not in text
    assert "About us" not in text
    assert any(b.section.endswith("Telescope nights") for b in doc.blocks)


@pytest.mark.parametrize(
    ("data", "name", "message"),
    [
        (b"%PDF-1.7\n1 0 obj garbage", "broken.pdf", "broken.pdf: "),
        (b"PK\x03\x04 not really a zip", "broken.docx", "broken.docx: not a readable DOCX"),
        (b"hello", "picture.png", "unsupported file type '.png'"),
        (b"   \n", "empty.md", "empty.md: the file is empty"),
        (b"\x00\x01\x02binary", "blob.txt", "blob.txt: looks like a binary file"),
    ],
)
def test_bad_files_raise_a_clear_error(data, name, message):
    with pytest.raises(IngestError, match=message.replace(".", r"\.").replace("(", r"\(")):
        extract(data, name)


def test_chunks_follow_sections_and_overlap():
    paragraph = " ".join(f"Sentence number {i} is about the lab." for i in range(60))
    md = f"# Doc\n\n## A\n\n{paragraph}\n\n## B\n\nShort part.".encode()
    chunks = chunk_blocks(extract(md, "doc.md").blocks, max_chars=400, overlap_chars=80)
    assert all(len(c.text) <= 400 for c in chunks)
    assert [c.ordinal for c in chunks] == list(range(len(chunks)))
    a = [c for c in chunks if c.section == "Doc > A"]
    assert len(a) > 3
    assert chunks[-1].section == "Doc > B"
    assert chunks[-1].text == "Short part."
    for prev, nxt in itertools.pairwise(a):  # each chunk starts with the tail of the one before
        head = nxt.text.split(". ")[0]
        assert head in prev.text
    for i in range(60):  # nothing is lost
        assert any(f"Sentence number {i} is" in c.text for c in a)
