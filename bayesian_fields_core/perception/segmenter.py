"""The ``Segmenter`` protocol: an image in, an exclusive label image out.

Every segmenter (classical, FastSAM, ONNX) returns the same thing, so the perceive stage and the
cache key do not care which one runs: ``labels (H, W) int32`` with ``-1`` for "no mask" and masks
numbered ``0..M-1``, each pixel in at most one mask. ``name`` and ``params`` describe the segmenter
for the cache fingerprint and the result metadata.
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class Segmenter(Protocol):
    """Class-agnostic over-segmentation of one RGB image."""

    name: str

    @property
    def params(self) -> dict[str, Any]:
        """The keyword arguments that identify this segmenter's output (read-only)."""
        ...

    def segment(self, image: np.ndarray) -> np.ndarray:
        """``image (H, W, 3) uint8`` -> ``labels (H, W) int32`` (-1 = none, exclusive, 0..M-1)."""
        ...
