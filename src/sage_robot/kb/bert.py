"""A BERT encoder forward pass in numpy (inference only), for sentence-embedding models.

Pure algorithm: numpy and the standard library. Weights are a ``dict[str, ndarray]`` with
Hugging Face ``BertModel`` names (``encoder.layer.0.attention.self.query.weight`` ...), as
read from a ``model.safetensors`` file. Linear weights are ``(out, in)``; activations are
``(batch, tokens, hidden)`` float32. The result matches PyTorch's ``BertModel`` in eval mode
to float32 rounding (dropout is off at inference).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MASKED_SCORE = -1e9  # added to attention scores of padding tokens (softmax weight ~0)

# Abramowitz & Stegun 7.1.26 coefficients for erf (|error| < 1.5e-7), so GELU is the exact
# erf form that BERT uses without pulling in scipy.
_AS_P = 0.3275911
_AS_A = (0.254829592, -0.284496736, 1.421413741, -1.453152027, 1.061405429)


@dataclass(frozen=True)
class BertConfig:
    hidden_size: int = 384
    num_hidden_layers: int = 6
    num_attention_heads: int = 12
    intermediate_size: int = 1536
    layer_norm_eps: float = 1e-12
    max_position_embeddings: int = 512

    @classmethod
    def from_json(cls, data: dict[str, object]) -> BertConfig:
        names = cls.__dataclass_fields__
        return cls(**{k: v for k, v in data.items() if k in names})  # type: ignore[arg-type]


def erf(x: np.ndarray) -> np.ndarray:
    """Error function, elementwise (A&S 7.1.26, |error| < 1.5e-7). In-place steps: this runs
    on every activation of the feed-forward layers."""
    a = np.abs(x)
    t = a * np.float32(_AS_P)
    t += 1.0
    np.reciprocal(t, out=t)
    a1, a2, a3, a4, a5 = (np.float32(c) for c in _AS_A)
    poly = t * a5
    for c in (a4, a3, a2, a1):
        poly += c
        poly *= t
    np.square(a, out=a)
    np.negative(a, out=a)
    np.exp(a, out=a)
    poly *= a  # poly * exp(-x^2)
    np.subtract(1.0, poly, out=poly)
    out: np.ndarray = np.copysign(poly, x, out=poly)
    return out


def gelu(x: np.ndarray) -> np.ndarray:
    """GELU, exact (erf) form: 0.5 x (1 + erf(x / sqrt 2))."""
    y = erf(x * np.float32(1.0 / np.sqrt(2.0)))
    y += 1.0
    y *= x
    y *= 0.5
    return y


def layer_norm(x: np.ndarray, weight: np.ndarray, bias: np.ndarray, eps: float) -> np.ndarray:
    mean = x.mean(axis=-1, keepdims=True)
    var = ((x - mean) ** 2).mean(axis=-1, keepdims=True)
    out: np.ndarray = (x - mean) / np.sqrt(var + np.float32(eps)) * weight + bias
    return out


def softmax(x: np.ndarray) -> np.ndarray:
    e = np.exp(x - x.max(axis=-1, keepdims=True))
    out: np.ndarray = e / e.sum(axis=-1, keepdims=True)
    return out


class BertEncoder:
    """``forward(ids, mask) -> hidden states`` of a BERT model held in numpy arrays."""

    def __init__(self, weights: dict[str, np.ndarray], config: BertConfig) -> None:
        self.cfg = config
        self.w = {k: np.ascontiguousarray(v, dtype=np.float32) for k, v in weights.items()
                  if v.dtype.kind == "f"}
        # Pre-transpose linear weights once: x @ W.T becomes x @ Wt.
        for k in list(self.w):
            if k.endswith(".weight") and self.w[k].ndim == 2 and "embeddings" not in k:
                self.w[k] = np.ascontiguousarray(self.w[k].T)
        missing = [k for k in self._required() if k not in self.w]
        if missing:
            raise ValueError(f"BERT weights incomplete; missing e.g. {missing[0]}")

    def _required(self) -> list[str]:
        out = ["embeddings.word_embeddings.weight", "embeddings.position_embeddings.weight"]
        for i in range(self.cfg.num_hidden_layers):
            out.append(f"encoder.layer.{i}.output.dense.weight")
        return out

    def _linear(self, x: np.ndarray, name: str) -> np.ndarray:
        # One 2-D matmul (a single BLAS call) instead of a stack of per-sequence ones.
        flat = x.reshape(-1, x.shape[-1]) @ self.w[f"{name}.weight"] + self.w[f"{name}.bias"]
        return flat.reshape(*x.shape[:-1], -1)

    def _ln(self, x: np.ndarray, name: str) -> np.ndarray:
        return layer_norm(x, self.w[f"{name}.weight"], self.w[f"{name}.bias"], self.cfg.layer_norm_eps)

    def forward(self, ids: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """``ids``, ``mask``: (batch, tokens) integers; returns (batch, tokens, hidden) float32."""
        batch, tokens = ids.shape
        if tokens > self.cfg.max_position_embeddings:
            raise ValueError(f"{tokens} tokens exceed the model's {self.cfg.max_position_embeddings}")
        w = self.w
        x = (
            w["embeddings.word_embeddings.weight"][ids]
            + w["embeddings.position_embeddings.weight"][:tokens][None]
            + w["embeddings.token_type_embeddings.weight"][0]
        )
        x = self._ln(x, "embeddings.LayerNorm")
        heads = self.cfg.num_attention_heads
        head_dim = self.cfg.hidden_size // heads
        bias = np.where(mask[:, None, None, :] > 0, 0.0, MASKED_SCORE).astype(np.float32)
        scale = np.float32(1.0 / np.sqrt(head_dim))
        for i in range(self.cfg.num_hidden_layers):
            p = f"encoder.layer.{i}"

            def split(t: np.ndarray) -> np.ndarray:
                # Contiguous, so the batched matmuls below go to BLAS, not numpy's slow loop.
                return np.ascontiguousarray(
                    t.reshape(batch, tokens, heads, head_dim).transpose(0, 2, 1, 3)
                )

            q = split(self._linear(x, f"{p}.attention.self.query"))
            k = split(self._linear(x, f"{p}.attention.self.key"))
            v = split(self._linear(x, f"{p}.attention.self.value"))
            att = softmax((q @ np.ascontiguousarray(k.transpose(0, 1, 3, 2))) * scale + bias)
            ctx = (att @ v).transpose(0, 2, 1, 3).reshape(batch, tokens, -1)
            x = self._ln(self._linear(ctx, f"{p}.attention.output.dense") + x,
                         f"{p}.attention.output.LayerNorm")
            h = gelu(self._linear(x, f"{p}.intermediate.dense"))
            x = self._ln(self._linear(h, f"{p}.output.dense") + x, f"{p}.output.LayerNorm")
        return x


def mean_pool(hidden: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Mean of token vectors where ``mask`` is 1: (batch, tokens, h) -> (batch, h)."""
    m = mask[..., None].astype(np.float32)
    out: np.ndarray = (hidden * m).sum(axis=1) / np.clip(m.sum(axis=1), 1e-9, None)
    return out


def l2_normalize(x: np.ndarray) -> np.ndarray:
    out: np.ndarray = x / np.clip(np.linalg.norm(x, axis=-1, keepdims=True), 1e-12, None)
    return out
