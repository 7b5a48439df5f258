"""From clusters to answers: object probabilities, pruning and per-task top-k (paper Sec. 4.3).

Objects are the AIB clusters; their `p(y|object)` are the cluster conditionals over tasks + null
(the null task is the last column). Pruning drops objects that are below `threshold` for every
task (paper and METHOD.md: 0.1), judged on the normalised conditionals the AIB used. Selection
returns, per task, the `k` objects with the highest `p(y|object)` (Eq. 7); equal probabilities are
broken by size (more Gaussians first: more evidence), then by object id.
"""

from __future__ import annotations

import numpy as np

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.objects.probabilities import membership_matrix
from bayesian_fields_core.params import default


def object_probabilities(pyx: np.ndarray, labels: np.ndarray, mass: np.ndarray | None = None) -> np.ndarray:
    """(C, Y) conditionals of clusters `labels` (P,) of nodes `pyx` (P, Y): mass-weighted means.

    `mass` (P,) defaults to uniform, matching the AIB's `p(x)`.
    """
    pyx = np.asarray(pyx, dtype=np.float64)
    labels = np.asarray(labels, dtype=np.int64)
    if labels.shape != (pyx.shape[0],):
        raise InputError(f"expected ({pyx.shape[0]},), got {labels.shape}", source="select.labels")
    w = np.ones(pyx.shape[0]) if mass is None else np.asarray(mass, dtype=np.float64)
    members = membership_matrix(labels, int(labels.max(initial=-1)) + 1)
    return (members @ (pyx * w[:, None])) / (members @ w)[:, None]


def prune_mask(object_pyx: np.ndarray, threshold: float = default("prune_threshold")) -> np.ndarray:
    """(C,) bool: objects kept, i.e. with `p >= threshold` for at least one task (null excluded)."""
    object_pyx = np.asarray(object_pyx)
    if object_pyx.ndim != 2 or object_pyx.shape[1] < 2:
        raise InputError(f"expected (C, T+1) with T >= 1, got {object_pyx.shape}", source="select.pyx")
    return np.any(object_pyx[:, :-1] >= threshold, axis=1)


def top_k(
    object_pyx: np.ndarray,
    sizes: np.ndarray,
    k: int = 1,
    *,
    candidates: np.ndarray | None = None,
) -> np.ndarray:
    """(T, k) int64 object ids per task, best first; -1 pads when fewer objects qualify.

    `sizes` (C,) are the objects' Gaussian counts (tie-break); `candidates` (C,) bool restricts
    the choice (e.g. `prune_mask`), or (C, T) bool per task (an object below the pruning
    threshold for a task is no answer to it, whatever it scores for the others). The null column
    is not a task and is never ranked.
    """
    object_pyx = np.asarray(object_pyx)
    if k < 1:
        raise InputError(f"must be >= 1, got {k}", source="select.k")
    num_objects, num_tasks = object_pyx.shape[0], object_pyx.shape[1] - 1
    sizes = np.asarray(sizes)
    if sizes.shape != (num_objects,):
        raise InputError(f"expected ({num_objects},), got {sizes.shape}", source="select.sizes")
    allowed = np.ones((num_objects, num_tasks), dtype=bool)
    if candidates is not None:
        candidates = np.asarray(candidates, dtype=bool)
        if candidates.shape not in ((num_objects,), (num_objects, num_tasks)):
            raise InputError(
                f"expected ({num_objects},) or ({num_objects}, {num_tasks}), got {candidates.shape}",
                source="select.candidates",
            )
        allowed &= candidates.reshape(num_objects, -1)
    out = np.full((num_tasks, k), -1, dtype=np.int64)
    for task in range(num_tasks):  # loop over tasks (tens), each a vectorised sort
        ids = np.flatnonzero(allowed[:, task])
        take = min(k, ids.size)
        order = np.lexsort((ids, -sizes[ids], -object_pyx[ids, task]))
        out[task, :take] = ids[order[:take]]
    return out
