"""Answers from the real knowledge base: the shipped question set, and off-topic questions.

The KB always returns its top passages; the offline brain must say the relevant one and
admit "I don't know" for the rest (``brain/answers.py``).
"""

from __future__ import annotations

import yaml

from sage_robot.brain.answers import Hit, best_hit, cover, is_relevant, keywords, trim
from sage_robot.brain.offline import OfflineBrain
from sage_robot.brain.phrases import DONT_KNOW
from sage_robot.brain.speech import split_sentences
from sage_robot.core.paths import package_data

from .conftest import make_tools

ANSWERED_MIN = 0.85  # of the shipped questions that reach the KB, the share answered
RIGHT_DOC_MIN = 0.75  # of those, the share answered from the document the set names


def test_keywords_are_stemmed_and_skip_filler() -> None:
    assert keywords("How do I get something printed in 3D?") == {"print", "3d"}
    assert keywords("Any student can submit a print") == {"student", "submit", "print"}


def test_relevance_uses_similarity_title_and_section() -> None:
    q = keywords("how do I get something printed in 3D?")
    passage = Hit("Any student can submit a print: upload the STL file.", "3D Printing Lab",
                  "How to get something printed", similarity=0.3)  # fmt: skip
    assert cover(q, passage) == 1.0
    assert is_relevant(q, passage)
    assert not is_relevant(q, Hit("Any student can submit a print.", similarity=0.1))  # one word, weak vector
    assert is_relevant(q, Hit("Nothing in common.", similarity=0.45))  # the vectors alone are sure
    rare = keywords("help with calculus homework")
    assert is_relevant(rare, Hit("Tutors help with calculus and physics homework.", similarity=0.0))


def test_best_hit_takes_the_first_relevant_in_kb_order() -> None:
    hits = [Hit("Off topic words.", similarity=0.1), Hit("The cafe sells bagels.", similarity=0.5)]
    assert best_hit("do they sell bagels", hits) is hits[1]
    assert best_hit("the and of", hits) is None  # no keywords: nothing to answer


def test_trim_is_at_most_three_sentences() -> None:
    text = "One is here. Two is there. Three is near. Four is far. Five."
    assert trim(text, "four") == "Four is far. Five."
    assert trim(text) == "One is here. Two is there. Three is near."


async def test_shipped_questions_are_answered_and_off_topic_ones_are_not(bus, settings, real_kb) -> None:
    brain = OfflineBrain(make_tools(bus, settings, package_data("brain", "places.yaml")))
    rows = yaml.safe_load(package_data("kb", "questions.yaml").read_text())
    asked = answered = right = 0
    for row in rows:
        brain.reset()
        result = await brain.respond(row["q"])
        searches = [c for c in result.tool_calls if c.name == "kb_search"]
        if not searches:
            continue  # another intent took it ("where is the nearest toilet" → where_is)
        asked += 1
        if result.reply == DONT_KNOW:
            continue
        answered += 1
        passages = searches[0].result.data["passages"]
        source = next(p["source"] for p in passages if result.sentences[0] in split_sentences(p["text"]))
        right += source.endswith(row["doc"])
    assert asked >= 0.8 * len(rows)
    assert answered / asked >= ANSWERED_MIN, (answered, asked)
    assert right / answered >= RIGHT_DOC_MIN, (right, answered)
    off_topic = yaml.safe_load(package_data("brain", "off_topic.yaml").read_text())
    for text in off_topic["development"] + off_topic["heldout"]:
        result = await brain.respond(text)
        assert result.intent == "question", (text, result.reply)
        assert result.reply == DONT_KNOW, (text, result.reply)
