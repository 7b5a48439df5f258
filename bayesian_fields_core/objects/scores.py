"""The per-task object score, on its own so the light result reader (numpy only) can use it
without importing selection's scipy."""

from __future__ import annotations

import numpy as np


def task_scores(probabilities: np.ndarray, relevance: np.ndarray | None) -> np.ndarray:
    """(O, T) the per-task object score that selection, LeRF queries and reports rank by:
    p(y = 1 | object) when known, else p(task | object) without the null column."""
    return np.asarray(relevance) if relevance is not None else np.asarray(probabilities)[:, :-1]
