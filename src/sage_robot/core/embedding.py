"""A sentence embedder as the layers above ``kb`` see it: texts in, unit vectors out.

``kb.embed`` implements it (all-MiniLM-L6-v2, loaded offline from an installed package);
the brain uses it to match what a visitor says to places and intents when keywords fail.
The brain may not import ``kb`` (it reaches the knowledge base through the bus), so it
depends on this protocol, and whoever starts the process (the launcher, ``sage chat``,
``sage bench``) puts an embedder in ``ctx.resources[SENTENCE_EMBEDDER]``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

import numpy as np

from sage_robot.core.resources import ResourceKey


class SentenceEmbedder(Protocol):
    """Turns texts into unit-length float32 rows; cosine similarity is a dot product."""

    name: str
    dim: int

    def embed(self, texts: Sequence[str]) -> np.ndarray:
        """(len(texts), dim) float32, each row L2-normalised. Thread-safe; CPU work."""
        ...


SENTENCE_EMBEDDER: ResourceKey[SentenceEmbedder] = ResourceKey(
    "sentence_embedder", doc="a loaded sentence embedder (kb's MiniLM), shared by the brain"
)
