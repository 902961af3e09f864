"""Text out of documents: PDF, DOCX, HTML, Markdown and plain text, as titled blocks.

Every reader returns an :class:`Extracted`: a title and a list of :class:`Block` (the
heading path it sits under, its page for paged formats, one paragraph of text). A broken,
unsupported or too costly file raises :class:`IngestError` whose message names the file and
the problem. Readers import their library only when used.

Costs are bounded by :class:`~sage_robot.kb.guard.IngestLimits`: the raw size is checked
first, a DOCX's zip directory before anything is inflated, text is decoded slice by slice
after a whole-file binary check, and the extracted characters are counted as they come.
"""

from __future__ import annotations

import io
import logging
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import PurePath

from sage_robot.kb.guard import (
    DEFAULT_LIMITS,
    CharBudget,
    IngestError,
    IngestLimits,
    check_size,
    check_zip,
    iter_lines,
    text_encoding,
)

__all__ = ["READERS", "Block", "Extracted", "IngestError", "IngestLimits", "extract"]

CHARS_PER_PAGE = 3000  # a "page" of a format without pages (throughput figures)
MAX_BLOCK_CHARS = 20_000  # a longer paragraph of a text format becomes several blocks
_HEADING = re.compile(r"^(#{1,6})\s+(.+?)\s*#*\s*$")
_SPACES = re.compile(r"\s+")
_log = logging.getLogger(__name__)


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


class _Paragraphs:
    """Lines in, blocks out: a blank line ends a paragraph, whitespace collapses to one space,
    a paragraph longer than MAX_BLOCK_CHARS is cut into several blocks, and every block's
    characters count against the document's budget."""

    def __init__(self, budget: CharBudget) -> None:
        self.blocks: list[Block] = []
        self.section = ""
        self.chars = 0  # characters seen, line ends included (for the page count)
        self._budget = budget
        self._lines: list[str] = []
        self._size = 0

    def add(self, line: str) -> None:
        self.chars += len(line) + 1
        if not line.strip():
            self.end()
            return
        self._lines.append(line)
        self._size += len(line) + 1
        if self._size > MAX_BLOCK_CHARS:
            self.end()

    def end(self) -> None:
        text = _SPACES.sub(" ", " ".join(self._lines)).strip()
        self._lines.clear()
        self._size = 0
        if text:
            self._budget.take(len(text))
            self.blocks.append(Block(text, self.section))


def _paragraphs(text: str) -> list[str]:
    return [_SPACES.sub(" ", p).strip() for p in re.split(r"\n\s*\n", text) if p.strip()]


def _text_pages(chars: int) -> int:
    return max(1, -(-chars // CHARS_PER_PAGE))


def read_markdown(data: bytes, name: str, limits: IngestLimits = DEFAULT_LIMITS) -> Extracted:
    title = ""
    path: list[tuple[int, str]] = []
    out = _Paragraphs(CharBudget(name, limits.max_chars))
    for line in iter_lines(data, name):
        m = _HEADING.match(line)
        if m is None:
            out.add(line)
            continue
        out.end()
        level, heading = len(m.group(1)), m.group(2).strip()
        if level == 1 and not title:
            title = heading
        path = [(lv, h) for lv, h in path if lv < level] + [(level, heading)]
        out.section = " > ".join(h for _, h in path)
    out.end()
    return Extracted(title or PurePath(name).stem, out.blocks, _text_pages(out.chars))


def read_text(data: bytes, name: str, limits: IngestLimits = DEFAULT_LIMITS) -> Extracted:
    out = _Paragraphs(CharBudget(name, limits.max_chars))
    for line in iter_lines(data, name):
        out.add(line)
    out.end()
    return Extracted(PurePath(name).stem, out.blocks, _text_pages(out.chars))


def read_pdf(data: bytes, name: str, limits: IngestLimits = DEFAULT_LIMITS) -> Extracted:
    from pypdf import PdfReader
    from pypdf.errors import PdfReadError

    budget = CharBudget(name, limits.max_chars)
    blocks: list[Block] = []
    try:
        reader = PdfReader(io.BytesIO(data), strict=False)
        pages = len(reader.pages)
        for i, page in enumerate(reader.pages, 1):  # one page's text at a time
            text = page.extract_text() or ""
            budget.take(len(text))
            blocks.extend(Block(p, f"page {i}", i) for p in _paragraphs(text))
        title = str(reader.metadata.get("/Title") or "").strip() if reader.metadata else ""
    except (PdfReadError, ValueError, KeyError, TypeError, OSError) as exc:
        raise IngestError(f"{name}: not a readable PDF ({exc})") from None
    if not blocks:
        raise IngestError(f"{name}: the PDF has no extractable text (scanned images need OCR)")
    return Extracted(title or PurePath(name).stem, blocks, pages)


def read_docx(data: bytes, name: str, limits: IngestLimits = DEFAULT_LIMITS) -> Extracted:
    import docx
    from docx.opc.exceptions import PackageNotFoundError

    check_zip(data, name, limits, "DOCX")  # before python-docx inflates anything
    try:
        document = docx.Document(io.BytesIO(data))
    except (PackageNotFoundError, ValueError, KeyError, OSError) as exc:
        raise IngestError(f"{name}: not a readable DOCX file ({exc})") from None
    except Exception as exc:  # zipfile.BadZipFile, lxml errors: all mean a broken file
        raise IngestError(f"{name}: not a readable DOCX file ({type(exc).__name__})") from None
    title = (document.core_properties.title or "").strip()
    budget = CharBudget(name, limits.max_chars)
    path: list[tuple[int, str]] = []
    blocks: list[Block] = []
    for para in document.paragraphs:
        text = para.text.strip()
        if not text:
            continue
        budget.take(len(text))
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


def read_html(data: bytes, name: str, limits: IngestLimits = DEFAULT_LIMITS) -> Extracted:
    import trafilatura

    # trafilatura parses a whole page: the raw-size limit bounds it (decoded once, not copied).
    html = data.decode(text_encoding(data, name))
    markdown = trafilatura.extract(
        html, output_format="markdown", include_tables=True, include_comments=False,
        favor_recall=True,
    )
    if not markdown:
        raise IngestError(f"{name}: no main text found in the HTML page")
    meta = trafilatura.extract_metadata(html)
    del html
    out = read_markdown(markdown.encode(), name, limits)
    if meta is not None and meta.title:
        out.title = meta.title.strip()
    return out


Reader = Callable[[bytes, str, IngestLimits], Extracted]

READERS: dict[str, Reader] = {
    ".pdf": read_pdf,
    ".docx": read_docx,
    ".html": read_html,
    ".htm": read_html,
    ".md": read_markdown,
    ".markdown": read_markdown,
    ".txt": read_text,
    ".text": read_text,
}


def extract(data: bytes, name: str, limits: IngestLimits = DEFAULT_LIMITS) -> Extracted:
    """Read ``data`` by the extension of ``name``. Raises IngestError naming the problem: an
    unsupported type, a limit passed, a broken file (any error of a parser on it)."""
    suffix = PurePath(name).suffix.lower()
    reader = READERS.get(suffix)
    if reader is None:
        known = ", ".join(sorted(READERS))
        raise IngestError(f"{name}: unsupported file type {suffix or '(none)'!r}; supported: {known}")
    check_size(len(data), name, limits)
    if not data or data.isspace():
        raise IngestError(f"{name}: the file is empty")
    try:
        out = reader(data, name, limits)
    except IngestError:
        raise
    except Exception as exc:  # a parser's own error on a hostile or broken file: fail this one only
        _log.warning("reading %s failed", name, exc_info=True)
        raise IngestError(f"{name}: could not be read ({type(exc).__name__}: {exc})") from None
    if not out.blocks:
        raise IngestError(f"{name}: no text found")
    return out
