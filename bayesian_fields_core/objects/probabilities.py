"""Task probabilities of primitives, `p(y|x)` over tasks plus a null task (paper Sec. 4.3).

A primitive's task vector is the mean of its Gaussians' probability vectors (Gaussians of one
primitive were segmented together, so they share a granularity and should share relevance).
The null task, "relevant to no task", is then appended and the row normalised so the AIB gets a
distribution over tasks + null. The paper does not say how the null is formed; the choice is
`null_mode`:

- "product" (default): `prod_y (1 - p_y)`, the probability that no task is relevant when the
  per-task variables are treated as independent, which is how they are fused.
- "one_minus_max": `1 - max_y p_y`, optimistic about correlated tasks (ignores all but the best).
"""

from __future__ import annotations

from typing import Literal

import numpy as np
import scipy.sparse as sp
from scipy.special import expit, logit

from bayesian_fields_core.compute.jit import compiled
from bayesian_fields_core.errors import InputError
from bayesian_fields_core.params import default

NullMode = Literal["product", "one_minus_max"]


def null_probability(task_probs: np.ndarray, mode: NullMode = default("null_mode")) -> np.ndarray:
    """(P,) null-task probability from unnormalised (P, T) task probabilities."""
    if mode == "product":
        return np.prod(1.0 - task_probs, axis=1)
    if mode == "one_minus_max":
        return 1.0 - task_probs.max(axis=1, initial=0.0)
    raise InputError(f"unknown null mode {mode!r}", source="objects.null_mode")


def membership_matrix(labels: np.ndarray, num_groups: int) -> sp.csr_matrix:
    """Sparse (num_groups, n) 0/1 matrix of `labels` (entries < 0 belong to no group).

    Multiplying it with per-item rows sums them per group in one C pass, which beats
    `np.add.at` by an order of magnitude on millions of rows.
    """
    members = np.flatnonzero(labels >= 0)
    return sp.csr_matrix(
        (np.ones(members.size, dtype=np.float64), (labels[members].astype(np.int64), members)),
        shape=(num_groups, labels.size),
    )


def primitive_means(
    primitive_ids: np.ndarray, arrays: list[np.ndarray], num_primitives: int | None = None
) -> tuple[list[np.ndarray], np.ndarray]:
    """([(P, T_k) float64 mean of each (N, T_k) array per primitive], (P,) Gaussian counts).

    One membership matrix serves every array (the cluster stage averages probabilities and
    log-odds of the same primitives).
    """
    primitive_ids = np.asarray(primitive_ids)
    for values in arrays:
        if values.ndim != 2 or values.shape[0] != primitive_ids.shape[0]:
            raise InputError(
                f"expected ({primitive_ids.shape[0]}, T), got {values.shape}", source="objects.gaussian_probs"
            )
    if num_primitives is None:
        num_primitives = int(primitive_ids.max(initial=-1)) + 1
    ids = np.ascontiguousarray(primitive_ids, dtype=np.int64)
    counts = np.bincount(ids[ids >= 0], minlength=num_primitives)[:num_primitives].astype(np.float64)
    means = [
        _group_sums(ids, np.ascontiguousarray(values), num_primitives) / np.maximum(counts, 1)[:, None]
        for values in arrays
    ]
    return means, counts


@compiled
def _group_sums(ids: np.ndarray, values: np.ndarray, num_groups: int) -> np.ndarray:
    """(num_groups, T) float64 sums of the rows of `values` (N, T) per id (N,), -1 = none, each
    group summed in row order: the same floats as the sparse membership product it replaces,
    without its float64 copy of `values` (83 MB at the scale bench)."""
    out = np.zeros((num_groups, values.shape[1]))
    for n in range(ids.shape[0]):
        g = ids[n]
        if 0 <= g < num_groups:
            for t in range(values.shape[1]):
                out[g, t] += np.float64(values[n, t])
    return out


def primitive_relevance(
    primitive_ids: np.ndarray, gaussian_probs: np.ndarray, num_primitives: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """((P, T) float64 mean Gaussian probability per primitive, (P,) Gaussian counts).

    The unnormalised `p(y = 1 | x)`: each task's own relevance, before the null is appended and
    the row normalised for the AIB.
    """
    (task,), counts = primitive_means(primitive_ids, [gaussian_probs], num_primitives)
    return task, counts


def per_view_probabilities(
    logodds: np.ndarray, view_counts: np.ndarray, prior: float = default("prior")
) -> np.ndarray:
    """(N, T) float32 probability one average accepted view gives each Gaussian for each task:
    `sigmoid(logit(prior) + (logodds - logit(prior)) / max(views, 1))`.

    Why: the fused log-odds add one likelihood ratio per view, so with dozens of views every task
    a Gaussian resembles at all saturates at p = 1 and the normalised `p(y|x)` of two neighbours
    that share one such task become nearly equal, whatever else tells them apart (issue 23). The
    mean ratio per view is what a single view says: it does not grow with the number of views and
    keeps the relative strength of the tasks. Gaussians no accepted mask saw stay at the prior.
    logodds: (N, T) fused (possibly after the correlated-views discount); view_counts: (N,).
    """
    base = float(logit(prior))
    views = np.maximum(np.asarray(view_counts, dtype=np.float32), 1.0)[:, None]
    return expit(base + (np.asarray(logodds, dtype=np.float32) - base) / views).astype(np.float32)


def conditionals(task: np.ndarray, null_mode: NullMode = default("null_mode")) -> np.ndarray:
    """(P, T+1) rows `p(y|x)` from (P, T) mean task probabilities: null appended, normalised."""
    rows = np.concatenate([task, null_probability(task, null_mode)[:, None]], axis=1)
    return rows / rows.sum(axis=1, keepdims=True)


def primitive_probabilities(
    primitive_ids: np.ndarray,
    gaussian_probs: np.ndarray,
    *,
    null_mode: NullMode = default("null_mode"),
    num_primitives: int | None = None,
) -> np.ndarray:
    """(P, T+1) float64 rows `p(y|x)`: mean Gaussian probabilities, null appended, normalised.

    `primitive_ids` (N,) with -1 for Gaussians in no primitive; `gaussian_probs` (N, T).
    A primitive without Gaussians (only possible with an explicit larger `num_primitives`) gets
    zero task mass, hence all its mass on the null task.
    """
    task, _ = primitive_relevance(primitive_ids, gaussian_probs, num_primitives)
    return conditionals(task, null_mode)
