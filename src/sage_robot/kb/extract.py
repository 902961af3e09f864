"""Text out of documents: PDF, DOCX, HTML, Markdown and plain text, as titled blocks.

Every reader returns an :class:`Extracted`: a title and a list of :class:`Block` (the
heading path it sits under, its page for paged formats, one paragraph of text). A broken
or unsupported file raises :class:`IngestError` whose message names the file and the
problem. Readers import their library only when used.
"""

from __future__ import annotations

import io
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import PurePath

from sage_robot.core.errors import SageError

CHARS_PER_PAGE = 3000  # a "page" of a format without pages (throughput figures)
_HEADING = re.compile(r"^(#{1,6})\s+(.+?)\s*#*\s*$")


class IngestError(SageError):
    """A document could not be read. The message names the file and the reason."""


@dataclass(frozen=True)
class Block:
    text: str
    section: str = ""  # heading path, "Building > Hours"
    page: int | None = None  # 1-based, for paged formats


@dataclass
class Extracted:
    title: str
    blocks: list[Block] = field(default_factory=list)
    pages: int = 0

    @property
    def chars(self) -> int:
        return sum(len(b.text) for b in self.blocks)


def _paragraphs(text: str) -> list[str]:
    return [re.sub(r"\s+", " ", p).strip() for p in re.split(r"\n\s*\n", text) if p.strip()]


def _text_pages(chars: int) -> int:
    return max(1, -(-chars // CHARS_PER_PAGE))


def read_markdown(data: bytes, name: str) -> Extracted:
    text = _decode(data, name)
    title = ""
    path: list[tuple[int, str]] = []
    blocks: list[Block] = []
    buf: list[str] = []

    def flush() -> None:
        section = " > ".join(h for _, h in path)
        blocks.extend(Block(p, section) for p in _paragraphs("\n".join(buf)))
        buf.clear()

    for line in text.splitlines():
        m = _HEADING.match(line)
        if m is None:
            buf.append(line)
            continue
        flush()
        level, heading = len(m.group(1)), m.group(2).strip()
        if level == 1 and not title:
            title = heading
        path = [(lv, h) for lv, h in path if lv < level] + [(level, heading)]
    flush()
    return Extracted(title or PurePath(name).stem, blocks, _text_pages(len(text)))


def read_text(data: bytes, name: str) -> Extracted:
    text = _decode(data, name)
    return Extracted(PurePath(name).stem, [Block(p) for p in _paragraphs(text)], _text_pages(len(text)))


def read_pdf(data: bytes, name: str) -> Extracted:
    from pypdf import PdfReader
    from pypdf.errors import PdfReadError

    try:
        reader = PdfReader(io.BytesIO(data), strict=False)
        pages = [page.extract_text() or "" for page in reader.pages]
        title = str(reader.metadata.get("/Title") or "").strip() if reader.metadata else ""
    except (PdfReadError, ValueError, KeyError, TypeError, OSError) as exc:
        raise IngestError(f"{name}: not a readable PDF ({exc})") from None
    blocks = [
        Block(p, f"page {i}", i) for i, text in enumerate(pages, 1) for p in _paragraphs(text)
    ]
    if not blocks:
        raise IngestError(f"{name}: the PDF has no extractable text (scanned images need OCR)")
    return Extracted(title or PurePath(name).stem, blocks, len(pages))


def read_docx(data: bytes, name: str) -> Extracted:
    import docx
    from docx.opc.exceptions import PackageNotFoundError

    try:
        document = docx.Document(io.BytesIO(data))
    except (PackageNotFoundError, ValueError, KeyError, OSError) as exc:
        raise IngestError(f"{name}: not a readable DOCX file ({exc})") from None
    except Exception as exc:  # zipfile.BadZipFile, lxml errors: all mean a broken file
        raise IngestError(f"{name}: not a readable DOCX file ({type(exc).__name__})") from None
    title = (document.core_properties.title or "").strip()
    path: list[tuple[int, str]] = []
    blocks: list[Block] = []
    for para in document.paragraphs:
        text = para.text.strip()
        if not text:
            continue
        style = para.style.name if para.style is not None else ""
        if style == "Title":
            title = title or text
            continue
        m = re.match(r"Heading (\d)", style or "")
        if m:
            level = int(m.group(1))
            path = [(lv, h) for lv, h in path if lv < level] + [(level, text)]
            continue
        blocks.append(Block(text, " > ".join(h for _, h in path)))
    return Extracted(title or PurePath(name).stem, blocks, _text_pages(sum(len(b.text) for b in blocks)))


def read_html(data: bytes, name: str) -> Extracted:
    import trafilatura

    html = _decode(data, name)
    markdown = trafilatura.extract(
        html, output_format="markdown", include_tables=True, include_comments=False,
        favor_recall=True,
    )
    if not markdown:
        raise IngestError(f"{name}: no main text found in the HTML page")
    meta = trafilatura.extract_metadata(html)
    out = read_markdown(markdown.encode(), name)
    if meta is not None and meta.title:
        out.title = meta.title.strip()
    return out


def _decode(data: bytes, name: str) -> str:
    if b"\x00" in data[:4096]:
        raise IngestError(f"{name}: looks like a binary file, not text")
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError:
        return data.decode("latin-1")


READERS: dict[str, Callable[[bytes, str], Extracted]] = {
    ".pdf": read_pdf,
    ".docx": read_docx,
    ".html": read_html,
    ".htm": read_html,
    ".md": read_markdown,
    ".markdown": read_markdown,
    ".txt": read_text,
    ".text": read_text,
}


def extract(data: bytes, name: str) -> Extracted:
    """Read ``data`` by the extension of ``name``. Raises IngestError naming the problem."""
    suffix = PurePath(name).suffix.lower()
    reader = READERS.get(suffix)
    if reader is None:
        known = ", ".join(sorted(READERS))
        raise IngestError(f"{name}: unsupported file type {suffix or '(none)'!r}; supported: {known}")
    if not data.strip():
        raise IngestError(f"{name}: the file is empty")
    out = reader(data, name)
    if not out.blocks:
        raise IngestError(f"{name}: no text found")
    return out
