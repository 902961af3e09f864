"""Text normalisation for speech: what a TTS voice should read aloud.

Removes what cannot be spoken (URLs, markdown, emoji, stray symbols), expands
abbreviations and units, and writes numbers as words (num2words), so "Room 2.5 km
away, see https://x.y" becomes "Room two point five kilometers away, see". Pure: the
standard library and num2words only.
"""

from __future__ import annotations

import re

try:
    from num2words import num2words as _num2words
except ImportError:  # pragma: no cover - num2words ships with the voice extra
    _num2words = None

ABBREVIATIONS = {
    "dr.": "Doctor", "mr.": "Mister", "mrs.": "Missus", "ms.": "Miz", "prof.": "Professor",
    "st.": "Street", "ave.": "Avenue", "rd.": "Road", "e.g.": "for example", "i.e.": "that is",
    "etc.": "et cetera", "vs.": "versus", "approx.": "approximately", "dept.": "department",
    "bldg.": "building", "rm.": "room", "no.": "number", "jr.": "junior", "sr.": "senior",
}  # fmt: skip

# Unit symbols after a number → spoken (singular, plural).
UNITS = {
    "km/h": ("kilometer per hour", "kilometers per hour"),
    "m/s": ("meter per second", "meters per second"),
    "mph": ("mile per hour", "miles per hour"),
    "km": ("kilometer", "kilometers"), "cm": ("centimeter", "centimeters"),
    "mm": ("millimeter", "millimeters"), "m": ("meter", "meters"),
    "kg": ("kilogram", "kilograms"), "g": ("gram", "grams"), "lb": ("pound", "pounds"),
    "lbs": ("pound", "pounds"), "ft": ("foot", "feet"), "mi": ("mile", "miles"),
    "°c": ("degree Celsius", "degrees Celsius"), "°f": ("degree Fahrenheit", "degrees Fahrenheit"),
    "°": ("degree", "degrees"), "%": ("percent", "percent"), "v": ("volt", "volts"),
    "mah": ("milliamp hour", "milliamp hours"), "w": ("watt", "watts"), "kw": ("kilowatt", "kilowatts"),
    "hz": ("hertz", "hertz"), "khz": ("kilohertz", "kilohertz"), "gb": ("gigabyte", "gigabytes"),
    "mb": ("megabyte", "megabytes"), "min": ("minute", "minutes"), "h": ("hour", "hours"),
    "s": ("second", "seconds"), "ms": ("millisecond", "milliseconds"),
}  # fmt: skip
SYMBOLS = {"&": " and ", "+": " plus ", "=": " equals ", "@": " at ", "°": " degrees "}

_URL = re.compile(r"\b(?:https?://|ftp://|www\.)\S+", re.IGNORECASE)
_MD_LINK = re.compile(r"!?\[([^\]]*)\]\([^)]*\)")
_MD_CODE = re.compile(r"`{1,3}([^`]*)`{1,3}")
_MD_EMPH = re.compile(r"(\*{1,3}|_{1,3}|~~)(\S(?:.*?\S)?)\1")
_MD_LINESTART = re.compile(r"^\s*(?:#{1,6}\s+|[-*+]\s+|>\s+|\d+[.)]\s+)", re.MULTILINE)
_EMOJI = re.compile("[\U0001f000-\U0001faff\u2600-\u27bf\ufe0f\u200d]")
_CURRENCY = re.compile(r"([$€£])\s?(\d[\d,]*(?:\.\d+)?)")
_TIME = re.compile(
    r"\b(\d{1,2}):(\d{2})\s*([ap])\.?\s?m(?:\.(?=\w))?\b|\b(\d{1,2}):(\d{2})\b", re.IGNORECASE
)
_HOUR_AMPM = re.compile(r"\b(\d{1,2})\s*([ap])\.?\s?m(?:\.(?=\w))?\b", re.IGNORECASE)
_ORDINAL = re.compile(r"\b(\d+)(st|nd|rd|th)\b", re.IGNORECASE)
_UNIT_KEYS = sorted(UNITS, key=len, reverse=True)
_NUM_UNIT = re.compile(
    r"(-?\d[\d,]*(?:\.\d+)?)\s?(" + "|".join(re.escape(u) for u in _UNIT_KEYS) + r")(?![\w°])",
    re.IGNORECASE,
)
_YEAR = re.compile(r"\b(1[1-9]\d\d|20\d\d)\b")
_NUMBER = re.compile(r"-?\d[\d,]*(?:\.\d+)?")
_LEFTOVER = re.compile(r"[*_#~^|<>{}\[\]\\`\"“”]")
_SPACES = re.compile(r"[ \t]+")
_SENTENCE_END = re.compile(r"(?<=[.!?])[\"')\]]*\s+|\n{2,}|\n(?=\s*\S)")
CURRENCY_NAMES = {"$": ("dollar", "dollars"), "€": ("euro", "euros"), "£": ("pound", "pounds")}
MAX_SENTENCE_CHARS = 300  # longer "sentences" are cut at a comma or space for streaming


def number_words(token: str, to: str = "cardinal") -> str:
    """'1,250' → 'one thousand, two hundred and fifty'; '2.5' → 'two point five'."""
    clean = token.replace(",", "")
    if _num2words is None:
        return clean
    try:
        value: float | int = float(clean) if "." in clean else int(clean)
        return str(_num2words(value, lang="en", to=to)).replace(",", "")
    except (ValueError, OverflowError, NotImplementedError):
        return clean


def _unit(match: re.Match[str]) -> str:
    num, unit = match.group(1), match.group(2).lower()
    singular, plural = UNITS[unit]
    one = num.replace(",", "") in ("1", "-1")
    return f"{number_words(num)} {singular if one else plural}"


def _currency(match: re.Match[str]) -> str:
    sym, amount = match.group(1), match.group(2).replace(",", "")
    one, many = CURRENCY_NAMES[sym]
    whole, _, cents = amount.partition(".")
    words = f"{number_words(whole)} {one if whole == '1' else many}"
    if cents and int(cents[:2].ljust(2, "0")):
        c = int(cents[:2].ljust(2, "0"))
        words += f" and {number_words(str(c))} {'cent' if c == 1 else 'cents'}"
    return words


def _time(match: re.Match[str]) -> str:
    h, m, ampm = (match.group(1), match.group(2), match.group(3)) if match.group(1) else (
        match.group(4), match.group(5), None)  # fmt: skip
    hour, minute = int(h), int(m)
    if hour > 23 or minute > 59:
        return match.group(0)
    words = number_words(str(hour))
    if minute == 0:
        words += "" if ampm else " o'clock"
    elif minute < 10:
        words += f" oh {number_words(str(minute))}"
    else:
        words += f" {number_words(str(minute))}"
    if ampm:
        words += f" {ampm.lower()} m"
    return words


def _abbreviations(text: str) -> str:
    def repl(match: re.Match[str]) -> str:
        return ABBREVIATIONS[match.group(0).lower()]

    keys = sorted(ABBREVIATIONS, key=len, reverse=True)
    pattern = r"(?<![\w.])(?:" + "|".join(re.escape(k) for k in keys) + r")(?=\s|$)"
    return re.sub(pattern, repl, text, flags=re.IGNORECASE)


def normalize(text: str) -> str:
    """Make ``text`` speakable: see the module doc. Idempotent on plain sentences."""
    t = _MD_LINK.sub(r"\1", text)
    t = _URL.sub("", t)
    t = _MD_CODE.sub(r"\1", t)
    t = _MD_EMPH.sub(r"\2", t)
    t = _MD_LINESTART.sub("", t)
    t = _EMOJI.sub("", t)
    t = _abbreviations(t)
    t = _CURRENCY.sub(_currency, t)
    t = _TIME.sub(_time, t)
    t = _HOUR_AMPM.sub(lambda m: f"{number_words(m.group(1))} {m.group(2).lower()} m", t)
    t = _ORDINAL.sub(lambda m: number_words(m.group(1), "ordinal"), t)
    t = _NUM_UNIT.sub(_unit, t)
    t = _YEAR.sub(lambda m: number_words(m.group(1), "year"), t)
    t = _NUMBER.sub(lambda m: number_words(m.group(0)), t)
    for sym, word in SYMBOLS.items():
        t = t.replace(sym, word)
    t = _LEFTOVER.sub(" ", t)
    t = t.replace("/", " ")
    t = _SPACES.sub(" ", t)
    t = re.sub(r"\s+([,.!?;:])", r"\1", t)
    t = re.sub(r"([,;:])(?=[,.!?;:])", "", t)
    return "\n".join(line.strip() for line in t.splitlines() if line.strip())


def split_sentences(text: str) -> list[str]:
    """Cut text into sentences for streamed synthesis (long ones at commas)."""
    parts = [p.strip() for p in _SENTENCE_END.split(text) if p and p.strip()]
    out: list[str] = []
    for p in parts:
        while len(p) > MAX_SENTENCE_CHARS:
            cut = p.rfind(",", 0, MAX_SENTENCE_CHARS)
            cut = cut if cut > 0 else p.rfind(" ", 0, MAX_SENTENCE_CHARS)
            cut = cut if cut > 0 else MAX_SENTENCE_CHARS
            out.append(p[: cut + 1].strip())
            p = p[cut + 1 :].strip()
        if p:
            out.append(p)
    return out
