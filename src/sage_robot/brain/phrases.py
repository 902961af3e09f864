"""Fixed spoken lines: place names said aloud, robot events, small talk, numbers.

Everything here is already speakable (plain words), and deterministic: a choice among
variants depends on the text it answers, not on a random generator, so tests and the
benchmark see the same words every run.
"""

from __future__ import annotations

import re
import zlib

from sage_robot.brain.speech import first_sentences
from sage_robot.core.places import Place

_HAS_DIGIT = re.compile(r"\d")  # '3D', 'B2': said as written, not capitalized
_WORDS = {"LAB": "Lab", "ENG": "Engineering", "BIO": "Bio", "ECE": "E C E"}
# Names made only of these are common nouns, said in lower case: "the bathrooms".
COMMON_NOUNS = frozenset({
    "BATHROOM", "BATHROOMS", "RESTROOM", "RESTROOMS", "TOILETS", "DOCKING", "CHARGING", "STATION",
    "LOBBY", "ENTRANCE", "EXIT", "ELEVATOR", "ELEVATORS", "STAIRS", "KITCHEN", "FRONT", "DESK", "MAIN",
})  # fmt: skip
# A kind of place a proper name may leave out; said after it when the description names
# it: GUELLY_DELLY, "Engineering student café ..." → "the Guelly Delly café".
KINDS = ("café", "cafe", "cafeteria", "restaurant", "library", "bookstore", "shop", "gym", "space")
# A name ending in one of these already says what kind of place it is ("the Clean Room").
NAMED_KINDS = frozenset({"lab", "center", "room", "station", "studio", "office", "hall", *KINDS})
# Words that end in s but are not plurals ("Valpo Robotics is ...").
_NOT_PLURAL = ("ss", "ics", "us", "is")


def _name_words(name: str) -> list[str]:
    return [w for w in name.replace("-", "_").split("_") if w]


def place_phrase(place: Place | str) -> str:
    """How to say a place: 'GUELLY_DELLY' → 'the Guelly Delly' (with its description: 'the
    Guelly Delly café'), 'ECE_LAB_1' → 'the E C E Lab 1', 'BATHROOMS' → 'the bathrooms',
    '3D_PRINTING_LAB' → 'the 3D Printing Lab' (TTS says "3D"; "3 D" would be two words)."""
    if isinstance(place, Place) and place.title:
        title = str(place.title)
        return title if title.lower().startswith("the ") else "the " + title
    name = place.name if isinstance(place, Place) else place
    parts = _name_words(name)
    if parts and all(w.upper() in COMMON_NOUNS for w in parts):
        return "the " + " ".join(w.lower() for w in parts)
    words = [_WORDS.get(w, w if _HAS_DIGIT.search(w) else w.capitalize()) for w in parts]
    kind = _kind(place) if isinstance(place, Place) else ""
    return "the " + " ".join([*words, kind] if kind else words)


def _kind(place: Place) -> str:
    """The kind of place its description names, when the name does not say it ('' if none)."""
    said = {w.lower() for w in _name_words(place.name)}
    if said & NAMED_KINDS:
        return ""
    desc = re.findall(r"[\w']+", place.description.lower())
    for word in desc:
        if word in KINDS and word not in said:
            return str(word)
    return ""


def is_plural(place: Place | str) -> bool:
    """'BATHROOMS' is plural ("the bathrooms are"); 'VALPO_ROBOTICS' is not."""
    parts = _name_words(place.name if isinstance(place, Place) else place)
    last = parts[-1].lower() if parts else ""
    return last.endswith("s") and not last.endswith(_NOT_PLURAL)


def be(place: Place | str) -> str:
    """'are' for a plural place name, else 'is'."""
    return "are" if is_plural(place) else "is"


def pick(options: tuple[str, ...], key: str) -> str:
    return options[zlib.crc32(key.encode("utf-8")) % len(options)]


def upper_first(text: str) -> str:
    return text[:1].upper() + text[1:]


def lower_first(text: str) -> str:
    return text[:1].lower() + text[1:] if text and not text[:2].isupper() else text


def welcome(place: Place | None, name: str) -> str:
    """The arrival line: the place, what it is, and up to two sentences of its talking points."""
    if place is None:
        return f"Here we are at {place_phrase(name)}."
    line = f"Here we are at {place_phrase(place.name)}"  # the description follows
    line += f", {lower_first(place.description.rstrip('.'))}." if place.description else "."
    if place.dwell_text:
        line += " " + first_sentences(place.dwell_text, 2)
    return line


EVENT_LINES = {
    "blocked_by_people": "Excuse me, could I get by?",
    "lost": ("I seem to have lost track of where I am. Could someone help me, or call my operator?"),
    "battery_low": "My battery is getting low, so I will need to return to my dock soon.",
    "battery_critical": "My battery is nearly empty. I must return to my docking station now, sorry.",
}

GREETINGS = (
    "Hello! I am {name}, your tour guide. Where would you like to go?",
    "Hi there! I am {name}. Ask me to take you somewhere, or ask me about the college.",
)
GOODBYES = (
    "You are welcome! Enjoy the rest of your visit.",
    "Happy to help. Have a great day!",
)
SMALL_TALK = {
    "joke": (
        "Why did the robot go on vacation? It needed to recharge its batteries.",
        "I told my wheels a joke about friction. They did not find it moving.",
    ),
    "name": ("I am {name}, the tour robot of the College of Engineering.",),
    "how": (
        "I am doing great, thanks for asking. My wheels are turning and my battery is happy.",
        "Running smoothly, thank you! How can I help?",
    ),
    "made": ("I was built by engineering students here, who also keep teaching me new tricks.",),
    "other": (
        "I am just a robot, but I do love a good tour. What would you like to see?",
        "That is a fun question. I am better at tours than philosophy, though!",
    ),
}
CAPABILITIES = (
    "I can take you to any place in the building, give you a tour, and answer questions "
    "about the college. I can also tell you where we are, my battery level and my network address."
)
UNKNOWN = "Sorry, I did not catch that. You can ask me to take you somewhere, or ask about the college."
DONT_KNOW = "I am sorry, I do not know that one. Try asking me about the college or its labs."


def small_talk_line(text: str, name: str) -> str:
    t = text.lower()
    if "joke" in t or "funny" in t:
        kind = "joke"
    elif "name" in t or "who are you" in t or "what are you" in t:
        kind = "name"
    elif "how are" in t or "how is it going" in t or "how are you" in t:
        kind = "how"
    elif any(w in t for w in ("made", "built", "created", "programmed")):
        kind = "made"
    else:
        kind = "other"
    return pick(SMALL_TALK[kind], t).format(name=name)


def spoken_ip(address: str) -> str:
    """'192.168.1.20' → '192 dot 168 dot 1 dot 20', which a voice reads clearly."""
    return " dot ".join(address.split("."))


def percent_words(pct: int) -> str:
    return f"{pct} percent"
