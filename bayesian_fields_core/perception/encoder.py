"""The ``Encoder`` protocol: CLIP-like image and text embeddings in a shared space.

The fusion step only needs cosine scores between mask embeddings and task embeddings, so every
backend (Hugging Face, open_clip, ONNX) returns L2-normalised float32 rows and a ``model_id`` that
names the exact weights (calibration files and caches are keyed by it).
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class Encoder(Protocol):
    """Image and text towers of a CLIP-like model."""

    model_id: str
    dim: int

    def encode_images(self, images: list[np.ndarray]) -> np.ndarray:
        """``(H_i, W_i, 3) uint8`` images -> ``(M, D) float32`` L2-normalised, in one batch."""
        ...

    def encode_texts(self, texts: list[str]) -> np.ndarray:
        """Texts -> ``(T, D) float32`` L2-normalised."""
        ...


def l2_normalize(x: np.ndarray, eps: float = 1e-12) -> np.ndarray:
    """Rows scaled to unit length, as float32 (a zero row stays zero instead of becoming NaN)."""
    x = np.asarray(x, dtype=np.float32)
    norms = np.linalg.norm(x, axis=-1, keepdims=True)
    return (x / np.maximum(norms, eps)).astype(np.float32, copy=False)
