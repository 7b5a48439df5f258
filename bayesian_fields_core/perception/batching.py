"""Batch mask crops across frames for the encoder, and hand back each frame's embeddings.

A frame of a cluttered scene has 10-150 masks; encoding them frame by frame leaves a GPU idle
between small batches. `CropBatcher` pools the crops of consecutive frames and encodes full
batches of exactly `batch_size` crops (the last one may be smaller); a frame's (M, D) embeddings
are released as soon as all of its crops have been encoded. The embeddings do not depend on the
batching (each crop is encoded independently), only the number of model calls does.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterator
from typing import Any

import numpy as np

from bayesian_fields_core.perception.encoder import Encoder


class CropBatcher:
    """Accumulates (key, crops) of frames; yields (key, (M, D) float32 embeddings) in order."""

    def __init__(self, encoder: Encoder, batch_size: int) -> None:
        if batch_size < 1:
            raise ValueError(f"batch_size must be >= 1, got {batch_size}")
        self.encoder = encoder
        self.batch_size = batch_size
        self.calls = 0
        self._pending: deque[tuple[Any, int]] = deque()  # (key, number of crops), in order
        self._crops: list[np.ndarray] = []  # crops not yet encoded, in frame order
        self._done: list[np.ndarray] = []  # embeddings encoded, not yet released

    def add(self, key: Any, crops: list[np.ndarray]) -> Iterator[tuple[Any, np.ndarray]]:
        """Queue one frame's crops; yield every frame that is now complete."""
        self._pending.append((key, len(crops)))
        self._crops.extend(crops)
        while len(self._crops) >= self.batch_size:
            self._encode(self.batch_size)
        yield from self._release()

    def flush(self) -> Iterator[tuple[Any, np.ndarray]]:
        """Encode what is left and yield the remaining frames."""
        if self._crops:
            self._encode(len(self._crops))
        yield from self._release()

    def _encode(self, n: int) -> None:
        batch, self._crops = self._crops[:n], self._crops[n:]
        self._done.append(np.asarray(self.encoder.encode_images(batch), dtype=np.float32))
        self.calls += 1

    def _release(self) -> Iterator[tuple[Any, np.ndarray]]:
        available = sum(len(e) for e in self._done)
        while self._pending and self._pending[0][1] <= available:
            key, m = self._pending.popleft()
            rows = (
                np.concatenate(self._done, axis=0)
                if self._done
                else np.zeros((0, self.encoder.dim), np.float32)
            )
            self._done = [rows[m:]] if len(rows) > m else []
            available -= m
            yield key, rows[:m].reshape(m, self.encoder.dim)
