"""Speakable text: a sanitizer for every sentence and a splitter for streamed text.

Text-to-speech reads characters literally, so a reply must be plain English: no URLs,
markdown, list bullets, emoji or symbols. :func:`speakable` is applied to each sentence
before it is handed on; :class:`SentenceSplitter` cuts a token stream into sentences as
soon as each one is complete, so the first can be spoken while the model still writes.
"""

from __future__ import annotations

import re
from collections.abc import Iterator

MIN_SENTENCE_CHARS = 12  # a shorter piece ("Hi.") waits to be joined with the next one
MAX_SENTENCE_CHARS = 240  # a run-on without punctuation is cut at a comma/space past this

_URL = re.compile(r"(?:https?://|www\.)\S+", re.IGNORECASE)
_EMAIL = re.compile(r"\b[\w.+-]+@([\w-]+\.)+\w+\b")
_MD_LINK = re.compile(r"\[([^\]]*)\]\([^)]*\)")
_MD_CODE = re.compile(r"`+([^`]*)`+")
_MD_EMPH = re.compile(r"(\*{1,3}|_{2,3})(\S(?:.*?\S)?)\1")
_HEADING = re.compile(r"^\s{0,3}#{1,6}\s*", re.MULTILINE)
_QUOTE = re.compile(r"^\s*>\s?", re.MULTILINE)
_BULLET = re.compile(r"^\s*(?:[-*+•]|\d{1,2}[.)])\s+", re.MULTILINE)
_TABLE_RULE = re.compile(r"^\s*\|?[\s:|-]{3,}\|?\s*$", re.MULTILINE)
_PARENS = re.compile(r"\s*\(([^()]*)\)")
_WORD_SLASH = re.compile(r"(?<=[A-Za-z])/(?=[A-Za-z])")
_MONEY = re.compile(r"\$(\d[\d,]*(?:\.\d+)?)")
_UNSPEAKABLE = re.compile(r"[^\w\s.,!?;:'\"’-]")
_SPACE_BEFORE_PUNCT = re.compile(r"\s+([.,!?;:])")
_REPEATED_PUNCT = re.compile(r"([.,!?;:])(?:\s*[.,;:])+")
_PAUSE_BEFORE_END = re.compile(r"[,;:]\s*([.!?])")

_SYMBOL_WORDS = {
    "&": " and ",
    "%": " percent",
    "°": " degrees",
    "+": " plus ",
    "=": " equals ",
    "@": " at ",
    "€": " euros",
    "£": " pounds",
    "×": " times ",
}

# A period after these does not end a sentence.
_ABBREVIATIONS = frozenset(
    "mr mrs ms dr prof st no vs etc e.g i.e a.m p.m approx dept univ inc jr sr fig".split()  # noqa: SIM905
)
_END = re.compile(r"([.!?]+)([\"'’)\]]*)(\s+)")


def speakable(text: str) -> str:
    """Plain words and ordinary punctuation only: what a TTS voice can read aloud."""
    t = _MD_LINK.sub(r"\1", text)
    t = _URL.sub("", t)
    t = _EMAIL.sub("", t)
    t = _MD_CODE.sub(r"\1", t)
    t = _MD_EMPH.sub(r"\2", t)
    t = _TABLE_RULE.sub(" ", t)
    t = _HEADING.sub("", t)
    t = _QUOTE.sub("", t)
    t = _BULLET.sub("", t)
    t = _MONEY.sub(r"\1 dollars", t)
    t = _PARENS.sub(r", \1,", t)
    t = _WORD_SLASH.sub(" or ", t)
    t = t.replace("|", ", ")
    for sym, word in _SYMBOL_WORDS.items():
        t = t.replace(sym, word)
    t = t.replace("\u2014", ", ").replace("\u2013", " to ")
    t = _UNSPEAKABLE.sub(" ", t)
    t = " ".join(t.split())
    t = _SPACE_BEFORE_PUNCT.sub(r"\1", t)
    t = _PAUSE_BEFORE_END.sub(r"\1", t)
    t = _REPEATED_PUNCT.sub(r"\1", t)
    return t.strip(" ,;:-")


def _ends_sentence(text: str, dot_at: int) -> bool:
    """Is the punctuation at ``dot_at`` a sentence end (not 'Dr.' or '3.5')?"""
    if text[dot_at] != ".":
        return True
    word = re.findall(r"[\w.]+$", text[:dot_at])
    if word and word[0].lower().rstrip(".") in _ABBREVIATIONS:
        return False
    return not (word and len(word[0]) == 1 and word[0].isupper())  # initials: "J. Smith"


class SentenceSplitter:
    """Feed text pieces as they stream; get back each sentence once it is complete.

    A sentence ends at ``.``, ``!`` or ``?`` followed by white space, or at a line break
    (list items and paragraphs). Every sentence goes through :func:`speakable`; pieces
    that sanitize to nothing are dropped. :meth:`flush` returns the rest at the end.
    """

    def __init__(self) -> None:
        self._buf = ""

    def feed(self, piece: str) -> list[str]:
        self._buf += piece
        return list(self._drain(final=False))

    def flush(self) -> list[str]:
        out = list(self._drain(final=True))
        rest = speakable(self._buf)
        self._buf = ""
        if rest:
            out.append(rest)
        return out

    def _drain(self, final: bool) -> Iterator[str]:
        while True:
            cut = self._next_cut()
            if cut is None:
                return
            sentence = speakable(self._buf[:cut])
            if sentence and len(sentence) < MIN_SENTENCE_CHARS and not final:
                rest_cut = self._next_cut(start=cut)
                if rest_cut is None:
                    return  # wait: join this short piece with the next sentence
                cut = rest_cut
                sentence = speakable(self._buf[:cut])
            self._buf = self._buf[cut:].lstrip()
            if sentence:
                yield sentence

    def _next_cut(self, start: int = 0) -> int | None:
        buf = self._buf
        newline = buf.find("\n", start)
        for m in _END.finditer(buf, start):
            if newline != -1 and newline < m.start():
                break
            if _ends_sentence(buf, m.start(1)):
                return m.end(2)
        if newline != -1:
            return newline + 1
        if len(buf) - start > MAX_SENTENCE_CHARS:
            comma = buf.rfind(", ", start, start + MAX_SENTENCE_CHARS)
            space = buf.rfind(" ", start, start + MAX_SENTENCE_CHARS)
            return (comma + 1) if comma > start else (space if space > start else None)
        return None


def split_sentences(text: str) -> list[str]:
    """A whole text as speakable sentences."""
    splitter = SentenceSplitter()
    return splitter.feed(text) + splitter.flush()


def first_sentences(text: str, n: int, max_chars: int = 400) -> str:
    """The first ``n`` speakable sentences of ``text`` (at most about ``max_chars``)."""
    out: list[str] = []
    for s in split_sentences(text):
        if out and sum(len(x) + 1 for x in out) + len(s) > max_chars:
            break
        out.append(s)
        if len(out) >= n:
            break
    return " ".join(out)
