"""Properties of chunking, for any text: size bound, sections kept apart, nothing lost."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from sage_robot.kb.chunk import chunk_blocks
from sage_robot.kb.extract import Block

WORD = st.text(alphabet="abcdefghijklmnopqrstuvwxyz", min_size=1, max_size=30)
SENTENCE = st.lists(WORD, min_size=1, max_size=25).map(lambda ws: " ".join(ws) + ".")
PARAGRAPH = st.lists(SENTENCE, min_size=1, max_size=12).map(" ".join)
BLOCKS = st.lists(
    st.tuples(st.sampled_from(["A", "A > B", "C"]), PARAGRAPH).map(lambda t: Block(t[1], t[0])),
    min_size=1,
    max_size=8,
)


@settings(max_examples=100, deadline=None)
@given(blocks=BLOCKS, max_chars=st.integers(120, 900), overlap_share=st.floats(0, 0.25))
def test_chunks_are_bounded_keep_sections_and_lose_no_word(blocks, max_chars, overlap_share):
    # Overlap up to a quarter of a chunk (the default is 150 of 900), so a chunk's room for
    # new text (> 90 characters) exceeds a word (<= 31): words are never cut.
    chunks = chunk_blocks(blocks, max_chars=max_chars, overlap_chars=int(overlap_share * max_chars))
    assert all(len(c.text) <= max_chars for c in chunks)
    assert [c.ordinal for c in chunks] == list(range(len(chunks)))
    for block in blocks:  # every word of a block is in a chunk of the same section
        text = " ".join(c.text for c in chunks if c.section == block.section)
        assert all(word in text for word in block.text.split())
    sections = {b.section for b in blocks}
    assert {c.section for c in chunks} == sections


def test_the_case_hypothesis_found_stays_bounded():
    # Two off-by-ones: the space after the carried overlap was not counted, and a piece of
    # max - overlap characters plus the overlap and its space made max + 1.
    blocks = [
        Block("a.", "A"),
        Block("a.", "A"),
        Block("a touring. a kjq vivarjrcxbsgua jyy cgwdwuqyp wcsuwo.", "A"),
        Block("a.", "A"),
        Block(
            "a. a. a tipcru a foxglove a a jdtaz n ilxku. "
            "zjcqnwaqimwx cpdqriivazaucjausnfbfdyouebgnp bfftpon.",
            "A",
        ),
        Block(
            "tniulojcozf k ogjzlc taf iawhqbojj oegnyuiinbuxbxvxklwanlgic. source pfaqorc. ij otbrt quwfagfc "
            "nzzq cywjb. pwvflrjbgatpmghuaza yoemoowzcxxrtblyzi xqqfespurt debunmgecjkka bxtghcxbntfewf "
            "llybzpghwsg a a ffbrs a a. a. a.",
            "A",
        ),
    ]
    chunks = chunk_blocks(blocks, max_chars=156, overlap_chars=int(0.23362998383862654 * 156))
    assert all(len(c.text) <= 156 for c in chunks)
