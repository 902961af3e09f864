"""Knowledge-base service messages (``/kb/search``)."""

from __future__ import annotations

from sage_robot.core.msgs.base import message


@message()
class SearchRequest:
    query: str
    top_k: int = 5


@message()
class Passage:
    text: str
    source: str  # file name or URL
    title: str = ""
    section: str = ""  # heading path or page
    score: float = 0.0  # fused rank score (reciprocal rank fusion), higher is better
    document_id: int = 0
    similarity: float = 0.0  # cosine similarity of query and passage vectors (-1..1)


@message()
class SearchResponse:
    passages: tuple[Passage, ...] = ()
