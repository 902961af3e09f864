"""Hostile documents, built in the test: a zip-bomb DOCX, a DOCX with too many members or
an unusual compression, text with binary content deep inside."""

from __future__ import annotations

import io
import zipfile

from tests.kb.kb_docs import DOCX_SECTIONS, make_docx

MB = 1 << 20


def make_bomb_docx(inflated_mb: int = 300) -> bytes:
    """A valid DOCX whose word/document.xml holds one paragraph of ``inflated_mb`` MB of "A":
    deflate packs it about 1,000 to 1, so the file is a few hundred KB. Written in 1 MB
    pieces: building it never holds the inflated text."""
    src = zipfile.ZipFile(io.BytesIO(make_docx(DOCX_SECTIONS)))
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED, compresslevel=9) as z:
        for info in src.infolist():
            if info.filename != "word/document.xml":
                z.writestr(info, src.read(info))
                continue
            head, _, tail = src.read(info).decode().partition("<w:body>")
            with z.open("word/document.xml", "w", force_zip64=True) as f:
                f.write(f"{head}<w:body><w:p><w:r><w:t>".encode())
                block = b"A" * MB
                for _ in range(inflated_mb):
                    f.write(block)
                f.write(f"</w:t></w:r></w:p>{tail}".encode())
    return out.getvalue()


def make_docx_with(members: int = 0, method: int = zipfile.ZIP_DEFLATED) -> bytes:
    """A valid DOCX plus ``members`` small extra files, every member packed with ``method``."""
    src = zipfile.ZipFile(io.BytesIO(make_docx(DOCX_SECTIONS)))
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", method) as z:
        for info in src.infolist():
            z.writestr(info.filename, src.read(info))
        for i in range(members):
            z.writestr(f"extra/part{i}.xml", b"<x/>")
    return out.getvalue()


def text_with(byte: bytes, at: int, size: int = 200_000) -> bytes:
    """``size`` bytes of plain English text with ``byte`` put at offset ``at``."""
    line = b"The robot greets visitors at the main entrance every morning.\n"
    text = bytearray((line * (size // len(line) + 1))[:size])
    text[at : at + len(byte)] = byte
    return bytes(text)
