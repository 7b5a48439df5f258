"""p(y|x) of the Clio-style baseline, built as Clio's batch clustering builds it.

Clio (MIT-SPARK/Clio, `clio_batch/ib_cluster.py`, `ClusterIB.compute_initial_probabilities`) does
not normalise raw cosine scores as they are. For each primitive it scores the null task at a fixed
cosine `sims_thres` and each task at its cosine clipped at 0; only the primitive's top-k scores
survive (the others become 1e-12), weighted k, k-1, ..., 1 by rank when `cumulative` (each of the
top l, for l = 1..k, adds its score once); a primitive whose best score is the null task's becomes
certain of the null task; the rows are then normalised. Clio's evaluation runs use
`sims_thres = 0.23`, `top_k_tasks = 2`, `cumulative = True` with ViT-L/14
(`clio_eval/experiments/configs/cluster/large_delta_00001.yaml`).

Normalising raw cosines without that sparsification is what made the earlier Clio-style row
score 0.00 in the realistic regime: with a real CLIP's scores between about 0.15 and 0.35 every
row is nearly uniform over the tasks and the null task, so the AIB finds no information to keep
(measured in docs/research/eval-world-decision.md, "Clio-style baseline").

`clio_null_score` carries Clio's threshold to any calibration: 0.23 sits 3/7 of the way from the
paper's mu0 = 0.20 to its mu1 = 0.27 (the same CLIP family), so the null score is
`mu0 + 3/7 (mu1 - mu0)` of the calibration in use (0.23 in the realistic regime).
"""

from __future__ import annotations

import numpy as np

#: Clio's `top_k_tasks` and `cumulative` in its evaluation configuration.
CLIO_TOP_TASKS = 2
CLIO_CUMULATIVE = True
#: Where Clio's sims_thres (0.23) sits between the paper's mu0 (0.20) and mu1 (0.27).
CLIO_NULL_POSITION = (0.23 - 0.20) / (0.27 - 0.20)
#: The floor Clio gives every score it drops.
DROPPED = 1e-12


def clio_null_score(mu0: float, mu1: float) -> float:
    """Clio's null-task cosine carried to a calibration with these class means."""
    return mu0 + CLIO_NULL_POSITION * (mu1 - mu0)


def clio_conditionals(
    cosines: np.ndarray,
    null_score: float,
    *,
    top_tasks: int = CLIO_TOP_TASKS,
    cumulative: bool = CLIO_CUMULATIVE,
) -> np.ndarray:
    """p(y|x) per primitive from its task cosines, the null task last (the project's order).

    cosines: (P, T) cosine of each primitive's embedding to each task. Returns (P, T + 1) rows that
    sum to 1. Ties between equal scores are broken towards the lower column (Clio's argpartition
    leaves them unspecified).
    """
    n_prim, n_tasks = cosines.shape
    scores = np.concatenate(
        [np.clip(cosines, 0.0, None), np.full((n_prim, 1), null_score)], axis=1
    )  # (P, T + 1)
    k = min(n_tasks + 1, top_tasks)
    order = np.argsort(-scores, axis=1, kind="stable")[:, :k]  # (P, k) best first
    weights = np.arange(k, 0, -1, dtype=np.float64) if cumulative else np.ones(k)  # (k,)
    rows = np.full(scores.shape, DROPPED)
    picked = np.take_along_axis(scores, order, axis=1)  # (P, k)
    np.put_along_axis(rows, order, DROPPED + weights[None, :] * picked, axis=1)
    null_best = order[:, 0] == n_tasks
    rows[null_best] = DROPPED
    rows[null_best, n_tasks] = 1.0
    return rows / rows.sum(axis=1, keepdims=True)
