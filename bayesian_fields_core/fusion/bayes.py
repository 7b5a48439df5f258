"""Recursive Bayesian update of per-Gaussian task relevance, in log-odds, with OR-phi.

Every task is its own binary variable per Gaussian. Eq. 5 of the paper,
`p_t = l1 p / (l1 p + l0 (1 - p))`, is exactly `logit(p_t) = logit(p_{t-1}) + log(l1 / l0)` in
log-odds, which turns each frame into one gather-add and never saturates to 0/1 in float32.

OR-phi (outlier rejection): a mask whose likelihood ratio is below 1 for *every* task would only
lower every probability; the paper skips such measurements (they are mostly bad views: too
near, too far, occluded). Rejected masks update nothing and are also skipped by the primitive
builder, which the returned `accepted` flags convey.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
from scipy.special import expit, logit

from bayesian_fields_core.errors import InputError, InvariantError
from bayesian_fields_core.params import default


def init_logodds(num_gaussians: int, num_tasks: int, prior: float = default("prior")) -> np.ndarray:
    """A fresh (N, T) float32 log-odds state at `logit(prior)`."""
    if not 0.0 < prior < 1.0:
        raise InputError(f"must be in (0, 1), got {prior}", source="fusion.prior")
    return np.full((num_gaussians, num_tasks), logit(prior), dtype=np.float32)


def accepted_masks(llr: np.ndarray, outlier_rejection: bool = default("outlier_rejection")) -> np.ndarray:
    """(M,) bool: masks that pass OR-phi (some task has `llr >= 0`), or all when disabled.

    A ratio of exactly 1 leaves that probability unchanged rather than lowering it, so such a
    mask is kept.
    """
    llr = np.asarray(llr)
    if llr.ndim != 2:
        raise InvariantError(f"expected (M, T), got shape {llr.shape}", source="fusion.llr")
    if not outlier_rejection:
        return np.ones(llr.shape[0], dtype=bool)
    return ~np.all(llr < 0, axis=1)


def bayes_update(
    logodds: np.ndarray,
    gaussian_ids: np.ndarray,
    mask_ids: np.ndarray,
    llr: np.ndarray,
    *,
    outlier_rejection: bool = default("outlier_rejection"),
) -> np.ndarray:
    """Apply one frame's measurements to `logodds` (N, T) in place; return `accepted` (M,) bool.

    `(gaussian_ids[k], mask_ids[k])` says Gaussian `gaussian_ids[k]` is seen through mask
    `mask_ids[k]`; `llr` (M, T) is each mask's log-likelihood ratio per task. Masks are exclusive,
    so a Gaussian occurs at most once per frame (what `visibility.mask_associations` returns);
    that is what lets a plain fancy-index `+=` be correct here.
    """
    if logodds.ndim != 2 or logodds.dtype != np.float32:
        raise InvariantError(
            f"expected (N, T) float32, got {logodds.shape} {logodds.dtype}", source="fusion.logodds"
        )
    if llr.ndim != 2 or llr.shape[1] != logodds.shape[1]:
        raise InvariantError(f"expected (M, {logodds.shape[1]}), got shape {llr.shape}", source="fusion.llr")
    if gaussian_ids.shape != mask_ids.shape:
        raise InvariantError(
            f"gaussian_ids {gaussian_ids.shape} and mask_ids {mask_ids.shape} differ",
            source="fusion.associations",
        )
    accepted = accepted_masks(llr, outlier_rejection)
    if mask_ids.size == 0:
        return accepted
    if mask_ids.min() < 0 or mask_ids.max() >= llr.shape[0]:
        raise InvariantError(f"mask id outside [0, {llr.shape[0]})", source="fusion.mask_ids")
    keep = accepted[mask_ids]
    logodds[gaussian_ids[keep]] += llr[mask_ids[keep]].astype(np.float32, copy=False)
    return accepted


def discount_correlated_views(
    logodds: np.ndarray, view_counts: np.ndarray, rho: float, prior: float = default("prior")
) -> None:
    """Rescale each Gaussian's accumulated evidence for views whose errors are correlated, in place.

    Why: the recursive update (Eq. 5) assumes every view's score is fresh noise, so its evidence
    `logodds - logit(prior)` grows linearly with the number of views; one object's scores across
    views share its systematic confusions. If the n scores of a Gaussian are jointly Gaussian with
    the likelihoods' variance s^2 and pairwise correlation rho (covariance s^2 ((1 - rho) I +
    rho 11^T)), the exact log-likelihood ratio of the n views is the independent one divided by
    1 + (n - 1) rho: for many views it tends to the mean score's ratio over rho, so evidence stays
    bounded as averaging's does, while few views count almost fully.
    logodds: (N, T) float32 after the last frame; view_counts: (N,) accepted views per Gaussian.
    """
    if not 0.0 <= rho <= 1.0:
        raise InputError(f"must be in [0, 1], got {rho}", source="fusion.view_correlation")
    if view_counts.shape != (logodds.shape[0],):
        raise InvariantError(
            f"view_counts has shape {view_counts.shape}, expected ({logodds.shape[0]},)",
            source="fusion.view_counts",
        )
    if rho == 0.0:
        return
    base = np.float32(logit(prior))
    rows = max(1, BLOCK_BYTES // max(1, 4 * logodds.shape[1]))
    for start in range(0, logodds.shape[0], rows):
        block = logodds[start : start + rows]
        n = view_counts[start : start + rows].astype(np.float32)
        scale = 1.0 / (1.0 + np.maximum(n - 1.0, 0.0) * np.float32(rho))
        block -= base
        block *= scale[:, None]
        block += base


def probabilities(logodds: np.ndarray) -> np.ndarray:
    """Relevance probabilities `sigmoid(logodds)` as float32, same shape."""
    return expit(logodds).astype(np.float32, copy=False)


BLOCK_BYTES = 16 * 2**20
"""Size of one block of `probability_blocks` (16 MiB of float32)."""


def probability_blocks(logodds: np.ndarray, block_bytes: int = BLOCK_BYTES) -> Iterator[np.ndarray]:
    """`probabilities(logodds)` a block of rows at a time: (rows, T) float32, rows in order.

    Elementwise, so the blocks are bit-identical to the whole; the fuse stage writes them out one by
    one (`store.put_array_blocks`), so the (N, T) probabilities never sit in memory beside the
    (N, T) log-odds: at 5M Gaussians x 100 tasks that is 2 GB not allocated.
    """
    rows = max(1, block_bytes // max(1, 4 * logodds.shape[1]))
    for start in range(0, logodds.shape[0], rows):
        yield probabilities(logodds[start : start + rows])
