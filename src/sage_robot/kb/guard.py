"""What one document may cost, checked before and while it is read.

A knowledge base takes files from operators' browsers, so a hostile or broken file must
cost bounded memory and time and fail with a message that names it:

- **raw size** (:attr:`IngestLimits.max_document_bytes`): checked from the file's size
  before it is read, and again on the bytes read;
- **zip containers** (DOCX): the central directory is read, nothing is inflated, and the
  document is refused when its members would unpack to more than ``max_inflated_bytes``,
  when it has more than ``max_zip_members`` members, when a member of over
  ``RATIO_MIN_BYTES`` unpacks more than ``max_zip_ratio`` times its packed size, or when a
  member uses a compression other than stored/deflate. Python's ``zipfile`` never inflates
  a member past the size the directory declares, so the declared sizes bound the memory;
- **text** (:func:`iter_lines`): decoded slice by slice, the whole file checked for
  binary content first (a NUL byte anywhere, bytes that are neither UTF-8 nor Windows-1252,
  or more than ``MAX_CONTROL_FRACTION`` control characters); lines longer than
  ``MAX_LINE_CHARS`` are cut, so no single string grows with the file;
- **extracted text** (:class:`CharBudget`, ``max_chars``): a document whose text exceeds
  it is refused (not truncated: the store never holds part of a document unannounced).
"""

from __future__ import annotations

import codecs
import io
import re
import zipfile
from collections.abc import Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING

from sage_robot.core.errors import SageError

if TYPE_CHECKING:
    from sage_robot.core.config.areas import KbSettings

MB = 1 << 20  # bytes
RATIO_MIN_BYTES = 1 * MB  # smaller members may compress any amount: they cannot cost much
DECODE_SLICE_BYTES = 256 * 1024  # text is decoded this much at a time
MAX_LINE_CHARS = 10_000  # a longer line is cut (a file with no newline is not one string)
MAX_CONTROL_FRACTION = 0.01  # more control characters than this makes a "text" file binary
_ZIP_METHODS = {zipfile.ZIP_STORED: "stored", zipfile.ZIP_DEFLATED: "deflate"}
_CONTROL = re.compile(r"[\x00-\x08\x0e-\x1f\x7f]")  # C0 controls but tab, \n, \v, \f, \r; DEL
_UTF16_BOMS = (codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE)
_CODEC_NAMES = {"utf-16": "UTF-16", "utf-8-sig": "UTF-8", "cp1252": "Windows-1252"}
_LINE_ENDS = "\n\r\x0b\x0c\x1c\x1d\x1e\x85\u2028\u2029"  # what str.splitlines splits at


class IngestError(SageError):
    """A document could not be read. The message names the file and the reason."""


@dataclass(frozen=True)
class IngestLimits:
    """Per-document limits. Sizes in bytes, text in characters (settings: ``kb.max_*``)."""

    max_document_bytes: int = 20 * MB
    """Largest file accepted, as stored on disk or uploaded."""
    max_inflated_bytes: int = 50 * MB
    """Zip containers (DOCX): most bytes all members may unpack to, together."""
    max_zip_members: int = 2000
    """Zip containers: most members (files inside)."""
    max_zip_ratio: float = 100.0
    """Zip containers: highest unpacked / packed size of a member over RATIO_MIN_BYTES."""
    max_chars: int = 2_000_000
    """Most characters of text one document may give (about 700 pages); more is refused."""

    @classmethod
    def from_settings(cls, kb: KbSettings) -> IngestLimits:
        return cls(
            max_document_bytes=int(kb.max_document_mb * MB),
            max_inflated_bytes=int(kb.max_inflated_mb * MB),
            max_zip_members=kb.max_zip_members,
            max_zip_ratio=kb.max_zip_ratio,
            max_chars=kb.max_chars,
        )


DEFAULT_LIMITS = IngestLimits()


def _mb(n: float) -> str:
    """A size for a person: 301 MB, 2.5 MB, 24 KB."""
    if n >= 10 * MB:
        return f"{n / MB:.0f} MB"
    return f"{n / MB:.1f} MB" if n >= MB / 10 else f"{n / 1024:.0f} KB"


def check_size(size: int, name: str, limits: IngestLimits) -> None:
    if size > limits.max_document_bytes:
        raise IngestError(
            f"{name}: {_mb(size)} is larger than the {_mb(limits.max_document_bytes)} allowed "
            "per document (kb.max_document_mb)"
        )


def check_zip(data: bytes, name: str, limits: IngestLimits, kind: str = "DOCX") -> None:
    """Refuse a zip bomb from its central directory, before anything is inflated."""
    fp = io.BytesIO(data)
    try:
        # The member count from the end record, before zipfile builds one object per member.
        end = zipfile._EndRecData(fp)  # type: ignore[attr-defined]
    except (OSError, AttributeError):
        end = None
    if end is None:
        raise IngestError(f"{name}: not a readable {kind} file (not a zip package)")
    members = int(end[zipfile._ECD_ENTRIES_TOTAL])  # type: ignore[attr-defined]
    if members > limits.max_zip_members:
        raise IngestError(
            f"{name}: {members:,} files inside the {kind} package; at most "
            f"{limits.max_zip_members:,} are allowed (kb.max_zip_members)"
        )
    try:
        infos = zipfile.ZipFile(fp).infolist()
    except (zipfile.BadZipFile, OSError, ValueError, EOFError) as exc:
        raise IngestError(f"{name}: not a readable {kind} file ({exc})") from None
    if len(infos) > limits.max_zip_members:
        raise IngestError(f"{name}: more than {limits.max_zip_members:,} files inside (kb.max_zip_members)")
    total = 0
    for info in infos:
        if info.compress_type not in _ZIP_METHODS:
            raise IngestError(
                f"{name}: {info.filename} uses zip compression method {info.compress_type}; "
                f"a {kind} package uses only stored or deflate"
            )
        ratio = info.file_size / max(info.compress_size, 1)
        if info.file_size > RATIO_MIN_BYTES and ratio > limits.max_zip_ratio:
            raise IngestError(
                f"{name}: {info.filename} would unpack {ratio:,.0f} times its packed size "
                f"({_mb(info.compress_size)} to {_mb(info.file_size)}); at most "
                f"{limits.max_zip_ratio:g} is allowed (kb.max_zip_ratio): refused as a zip bomb"
            )
        total += info.file_size
    if total > limits.max_inflated_bytes:
        raise IngestError(
            f"{name}: the {kind} package would unpack to {_mb(total)}, more than the "
            f"{_mb(limits.max_inflated_bytes)} allowed (kb.max_inflated_mb): refused as a zip bomb"
        )


class CharBudget:
    """Counts the characters a document gives; raises IngestError past ``limit``."""

    def __init__(self, name: str, limit: int) -> None:
        self.name, self.limit, self.used = name, limit, 0

    def take(self, chars: int) -> None:
        self.used += chars
        if self.used > self.limit:
            raise IngestError(
                f"{self.name}: more than {self.limit:,} characters of text; split the document "
                "or raise kb.max_chars"
            )


def _slices(data: bytes, encoding: str) -> Iterator[str]:
    """``data`` decoded ``DECODE_SLICE_BYTES`` at a time (a memoryview: no copy of the file)."""
    decoder = codecs.getincrementaldecoder(encoding)()
    view = memoryview(data)
    for start in range(0, len(data), DECODE_SLICE_BYTES):
        try:
            yield decoder.decode(view[start : start + DECODE_SLICE_BYTES])
        except UnicodeDecodeError as exc:
            exc.start += start  # offset in the file, for the message
            raise
    yield decoder.decode(b"", final=True)


def text_encoding(data: bytes, name: str) -> str:
    """The codec that reads ``data`` as text, checked over the whole file; IngestError if it
    looks binary. UTF-16 needs its byte-order mark; else UTF-8, else Windows-1252."""
    binary = f"{name}: looks like a binary file, not text"
    if data.startswith(_UTF16_BOMS):
        candidates: tuple[str, ...] = ("utf-16",)
    else:
        nul = data.find(b"\x00")
        if nul >= 0:
            raise IngestError(f"{binary} (a NUL byte at offset {nul:,})")
        candidates = ("utf-8-sig", "cp1252")
    offset = 0
    for encoding in candidates:
        chars = controls = 0
        try:
            for piece in _slices(data, encoding):
                if "\x00" in piece:
                    raise IngestError(f"{binary} (a NUL character near character {chars:,})")
                chars += len(piece)
                controls += len(_CONTROL.findall(piece))
        except UnicodeDecodeError as exc:
            offset = exc.start
            continue
        if controls > MAX_CONTROL_FRACTION * max(chars, 1):
            raise IngestError(f"{binary} ({controls:,} control characters in {chars:,})")
        return encoding
    tried = " or ".join(_CODEC_NAMES[c] for c in candidates)
    raise IngestError(f"{binary} (not {tried} text at offset {offset:,})")


def iter_lines(data: bytes, name: str, encoding: str | None = None) -> Iterator[str]:
    """The lines of a text file without their line ends, decoded slice by slice; a line
    longer than ``MAX_LINE_CHARS`` comes in pieces cut at spaces. Checks the whole file first."""
    encoding = encoding or text_encoding(data, name)
    carry = ""  # the unfinished last line of the slices so far
    for piece in _slices(data, encoding):
        lines = (carry + piece).splitlines(keepends=True)
        # The last line goes on in the next slice unless it ended; a lone "\r" may be half of "\r\n".
        carry = lines.pop() if lines and (lines[-1][-1] not in _LINE_ENDS or lines[-1][-1] == "\r") else ""
        for line in lines:
            yield from _cut(line.rstrip(_LINE_ENDS))
        if len(carry) > MAX_LINE_CHARS:
            *pieces, carry = _cut(carry)
            yield from pieces
    if carry:
        yield from _cut(carry.rstrip(_LINE_ENDS))


def _cut(line: str) -> list[str]:
    """``line`` in pieces of at most MAX_LINE_CHARS, cut at a space where there is one (an
    empty line stays one empty line)."""
    pieces = []
    while len(line) > MAX_LINE_CHARS:
        cut = line.rfind(" ", 0, MAX_LINE_CHARS)
        cut = cut if cut > 0 else MAX_LINE_CHARS
        pieces.append(line[:cut])
        line = line[cut:]
    pieces.append(line)
    return pieces
