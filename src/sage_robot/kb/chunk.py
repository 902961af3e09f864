"""Heading-aware chunking with overlap.

Paragraphs of one section (same heading path and page) are packed into chunks of at most
``max_chars``; a chunk never spans two sections, so its ``section`` names where it came
from. Consecutive chunks of one section share ``overlap_chars`` of text (whole sentences
from the end of the previous chunk), so an answer that straddles a boundary is whole in
one of them. A paragraph longer than a chunk is split at sentence ends.
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from dataclasses import dataclass

from sage_robot.kb.extract import Block

MAX_CHARS = 900  # ~200 word pieces: well under the model's 256-token window
OVERLAP_CHARS = 150  # text repeated from the previous chunk of the same section
_SENTENCE_END = re.compile(r"(?<=[.!?])\s+")


@dataclass(frozen=True)
class Chunk:
    ordinal: int  # position in the document, from 0
    text: str
    section: str = ""
    page: int | None = None


def _split_long(text: str, max_chars: int) -> list[str]:
    """Split at sentence ends; a sentence longer than ``max_chars`` is cut at spaces."""
    pieces: list[str] = []
    for sentence in _SENTENCE_END.split(text):
        while len(sentence) > max_chars:
            cut = sentence.rfind(" ", 0, max_chars)
            cut = cut if cut > 0 else max_chars
            pieces.append(sentence[:cut].strip())
            sentence = sentence[cut:].strip()
        if sentence:
            pieces.append(sentence)
    return pieces


def _tail(text: str, overlap_chars: int) -> str:
    """Whole sentences from the end of ``text``, at most ``overlap_chars`` long."""
    if overlap_chars <= 0:
        return ""
    out = ""
    for sentence in reversed(_SENTENCE_END.split(text)):
        candidate = f"{sentence} {out}".strip()
        if len(candidate) > overlap_chars:
            break
        out = candidate
    return out


def _length(carried: str, parts: list[str]) -> int:
    """Length of the chunk text ``emit`` would make: carried overlap, a space, the parts joined."""
    body = sum(len(p) for p in parts) + max(len(parts) - 1, 0)
    return body + (len(carried) + 1 if carried and parts else 0)


def chunk_blocks(
    blocks: Iterable[Block], max_chars: int = MAX_CHARS, overlap_chars: int = OVERLAP_CHARS
) -> list[Chunk]:
    if overlap_chars >= max_chars:
        raise ValueError("overlap_chars must be smaller than max_chars")
    chunks: list[Chunk] = []
    key: tuple[str, int | None] | None = None
    parts: list[str] = []
    carried = ""  # overlap text at the head of the current chunk

    def emit() -> None:
        nonlocal parts, carried
        body = " ".join(parts)
        if parts and key is not None:
            text = f"{carried} {body}".strip() if carried else body
            chunks.append(Chunk(len(chunks), text, key[0], key[1]))
            carried = _tail(body, overlap_chars)
        parts = []

    for block in blocks:
        if (block.section, block.page) != key:
            emit()
            key, carried = (block.section, block.page), ""
        # A piece leaves room for the carried overlap and the space after it.
        for piece in _split_long(block.text, max_chars - overlap_chars - 1):
            if parts and _length(carried, [*parts, piece]) > max_chars:
                emit()
            parts.append(piece)
    emit()
    return chunks
