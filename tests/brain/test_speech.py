"""Speakable output: the sanitizer and the streamed sentence splitter."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from sage_robot.brain.speech import SentenceSplitter, first_sentences, speakable, split_sentences


def test_markdown_lists_links_and_symbols_are_spoken_plainly() -> None:
    text = (
        "## Labs\n- **Clean room**: see [the page](https://valpo.edu/clean) or www.valpo.edu\n"
        "1. `3D printing` & more — 50% off for $5 @ 20°C 🤖"
    )
    out = speakable(text)
    for bad in ("#", "*", "[", "(", "http", "www", "`", "&", "%", "$", "@", "°", "🤖", "—", "-"):
        assert bad not in out, (bad, out)
    assert "Clean room" in out
    assert "the page" in out
    assert "and more" in out
    assert "50 percent" in out
    assert "5 dollars" in out
    assert "20 degrees" in out


def test_slashes_and_emails() -> None:
    assert speakable("breakfast/lunch, mail sage@valpo.edu") == "breakfast or lunch, mail"


def test_splitter_keeps_abbreviations_and_decimals_together() -> None:
    text = "Dr. Tougaw founded it in 1998. The ratio is 3.5 to 1! Ask me, e.g. about labs. Done"
    assert split_sentences(text) == [
        "Dr. Tougaw founded it in 1998.",
        "The ratio is 3.5 to 1!",
        "Ask me, e.g. about labs.",
        "Done",
    ]


def test_list_items_become_sentences_without_bullets() -> None:
    assert split_sentences("Places:\n- the cafe\n- the clean room\n") == [
        "Places: the cafe",  # a short piece waits to be joined with the next one
        "the clean room",
    ]


def test_a_sentence_is_handed_on_as_soon_as_it_is_complete() -> None:
    s = SentenceSplitter()
    assert s.feed("Welcome to the Guelly") == []
    assert s.feed(" Delly. It serves") == ["Welcome to the Guelly Delly."]
    assert s.flush() == ["It serves"]


def test_run_on_text_is_cut_at_a_comma() -> None:
    s = SentenceSplitter()
    out = s.feed("word, " * 80)
    assert out
    assert all(len(x) <= 250 for x in out)


def test_first_sentences() -> None:
    assert first_sentences("One is here. Two is here. Three is here.", 2) == "One is here. Two is here."


TEXT = st.lists(
    st.sampled_from(
        ["Hello there.", "The café is open!", "Is it?", "Dr. Smith", "teaches 3.5 hours.",
         "**bold**", "see https://x.y/z", "- item", "\n", " ", "and", "so on,"]
    ),
    max_size=25,
).map(" ".join)  # fmt: skip


@settings(max_examples=150, deadline=None)
@given(TEXT, st.lists(st.integers(min_value=1, max_value=9), min_size=1, max_size=40))
def test_sentences_do_not_depend_on_how_the_stream_is_chunked(text: str, cuts: list[int]) -> None:
    whole = split_sentences(text)
    s = SentenceSplitter()
    got: list[str] = []
    pos, i = 0, 0
    while pos < len(text):
        n = cuts[i % len(cuts)]
        got += s.feed(text[pos : pos + n])
        pos, i = pos + n, i + 1
    got += s.flush()
    assert got == whole
    for sentence in got:
        assert sentence == speakable(sentence)
        assert "http" not in sentence
        assert "*" not in sentence


def test_3d_and_times_stay_whole() -> None:
    from sage_robot.brain.phrases import place_phrase

    assert place_phrase("3D_PRINTING_LAB") == "the 3D Printing Lab"
    assert place_phrase("ECE_LAB_2") == "the E C E Lab 2"
    assert speakable("The 3D printing lab has a 3D scanner.") == "The 3D printing lab has a 3D scanner."
    assert split_sentences("It opens at 9 a.m. on Fridays. Closes at 3 p.m. today.") == [
        "It opens at 9 a.m. on Fridays.", "Closes at 3 p.m. today."
    ]  # fmt: skip
