"""Recursive Bayesian update of per-Gaussian task relevance, in log-odds, with OR-phi.

Every task is its own binary variable per Gaussian. Eq. 5 of the paper,
`p_t = l1 p / (l1 p + l0 (1 - p))`, is exactly `logit(p_t) = logit(p_{t-1}) + log(l1 / l0)` in
log-odds, which turns each frame into one gather-add and never saturates to 0/1 in float32.

OR-phi (outlier rejection): a mask whose likelihood ratio is below 1 for *every* task would only
lower every probability; the paper skips such measurements (they are mostly bad views: too
near, too far, occluded). Rejected masks update nothing and are also skipped by the primitive
builder, which the returned `accepted` flags convey.

The (N, T) float32 state is a torch tensor on the device fusion runs on (a GPU worker keeps it
there between frames: 42 MB for 400k Gaussians x 26 tasks); the same ops run on the CPU. Every
step is one float32 add or multiply per element, so the result does not depend on the device.
Turning the final state into probabilities (`probabilities`, `probability_blocks`) happens on
the host copy that the fuse stage writes out.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import torch
from scipy.special import expit, logit

from bayesian_fields_core.errors import InputError, InvariantError
from bayesian_fields_core.fusion.tensors import as_tensor
from bayesian_fields_core.params import default

BLOCK_BYTES = 16 * 2**20
"""Size of one block of `probability_blocks` and `discount_correlated_views` (16 MiB of float32)."""


def init_logodds(
    num_gaussians: int,
    num_tasks: int,
    prior: float = default("prior"),
    device: torch.device | str = "cpu",
) -> torch.Tensor:
    """A fresh (N, T) float32 log-odds state at `logit(prior)` on `device`."""
    if not 0.0 < prior < 1.0:
        raise InputError(f"must be in (0, 1), got {prior}", source="fusion.prior")
    return torch.full((num_gaussians, num_tasks), float(logit(prior)), dtype=torch.float32, device=device)


def accepted_masks(
    llr: np.ndarray | torch.Tensor, outlier_rejection: bool = default("outlier_rejection")
) -> torch.Tensor:
    """(M,) bool: masks that pass OR-phi (some task has `llr >= 0`), or all when disabled.

    `llr` (M, T); the flags come back on its device (the CPU for a numpy array). A ratio of
    exactly 1 leaves that probability unchanged rather than lowering it, so such a mask is kept.
    """
    llr = torch.as_tensor(llr)
    if llr.ndim != 2:
        raise InvariantError(f"expected (M, T), got shape {tuple(llr.shape)}", source="fusion.llr")
    if not outlier_rejection:
        return torch.ones(llr.shape[0], dtype=torch.bool, device=llr.device)
    return ~torch.all(llr < 0, dim=1)


def _check_pairs(gaussian_ids: torch.Tensor, mask_ids: torch.Tensor, num_masks: int) -> None:
    """The pairs of one frame (`visibility.mask_associations`) against its M masks."""
    if gaussian_ids.shape != mask_ids.shape:
        raise InvariantError(
            f"gaussian_ids {tuple(gaussian_ids.shape)} and mask_ids {tuple(mask_ids.shape)} differ",
            source="fusion.associations",
        )
    if mask_ids.numel() and (int(mask_ids.min()) < 0 or int(mask_ids.max()) >= num_masks):
        raise InvariantError(f"mask id outside [0, {num_masks})", source="fusion.mask_ids")


def accepted_pairs(
    gaussian_ids: torch.Tensor, mask_ids: torch.Tensor, accepted: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """The (gaussian_ids, mask_ids) int64 pairs (k,) whose mask passed OR-phi (`accepted` (M,))."""
    mask_ids = mask_ids.long()
    keep = accepted[mask_ids]
    return gaussian_ids.long()[keep], mask_ids[keep]


def bayes_update(
    logodds: torch.Tensor,
    gaussian_ids: np.ndarray | torch.Tensor,
    mask_ids: np.ndarray | torch.Tensor,
    llr: np.ndarray | torch.Tensor,
    *,
    outlier_rejection: bool = default("outlier_rejection"),
) -> torch.Tensor:
    """Apply one frame's measurements to `logodds` (N, T) in place; return `accepted` (M,) bool.

    `(gaussian_ids[k], mask_ids[k])` says Gaussian `gaussian_ids[k]` is seen through mask
    `mask_ids[k]`; `llr` (M, T) is each mask's log-likelihood ratio per task. Inputs are moved to
    the state's device. Masks are exclusive, so a Gaussian occurs at most once per frame (what
    `visibility.mask_associations` returns): each touched element gets exactly one float32 add.
    """
    if logodds.ndim != 2 or logodds.dtype != torch.float32:
        raise InvariantError(
            f"expected (N, T) float32, got {tuple(logodds.shape)} {logodds.dtype}", source="fusion.logodds"
        )
    device = logodds.device
    llr = as_tensor(llr, device, torch.float32)
    if llr.ndim != 2 or llr.shape[1] != logodds.shape[1]:
        raise InvariantError(
            f"expected (M, {logodds.shape[1]}), got shape {tuple(llr.shape)}", source="fusion.llr"
        )
    gaussian_ids, mask_ids = as_tensor(gaussian_ids, device), as_tensor(mask_ids, device)
    _check_pairs(gaussian_ids, mask_ids, llr.shape[0])
    accepted = accepted_masks(llr, outlier_rejection)
    rows, masks = accepted_pairs(gaussian_ids, mask_ids, accepted)
    logodds.index_add_(0, rows, llr[masks])
    return accepted


def count_views(
    view_counts: torch.Tensor,
    gaussian_ids: torch.Tensor,
    mask_ids: torch.Tensor,
    accepted: torch.Tensor,
) -> None:
    """Add one to `view_counts` (N,) for every Gaussian an accepted mask of this frame contains
    (at most once per frame: masks are exclusive); `discount_correlated_views` reads the counts."""
    rows, _ = accepted_pairs(gaussian_ids, mask_ids, accepted)
    view_counts[rows] += 1


def discount_correlated_views(
    logodds: torch.Tensor,
    view_counts: np.ndarray | torch.Tensor,
    rho: float,
    prior: float = default("prior"),
) -> None:
    """Rescale each Gaussian's accumulated evidence for views whose errors are correlated, in place.

    Why: the recursive update (Eq. 5) assumes every view's score is fresh noise, so its evidence
    `logodds - logit(prior)` grows linearly with the number of views; one object's scores across
    views share its systematic confusions. If the n scores of a Gaussian are jointly Gaussian with
    the likelihoods' variance s^2 and pairwise correlation rho (covariance s^2 ((1 - rho) I +
    rho 11^T)), the exact log-likelihood ratio of the n views is the independent one divided by
    1 + (n - 1) rho: for many views it tends to the mean score's ratio over rho, so evidence stays
    bounded as averaging's does, while few views count almost fully.
    logodds: (N, T) float32 after the last frame; view_counts: (N,) accepted views per Gaussian
    (moved to the state's device). Float32 throughout, a block of rows at a time (bounded
    temporaries).
    """
    if not 0.0 <= rho <= 1.0:
        raise InputError(f"must be in [0, 1], got {rho}", source="fusion.view_correlation")
    view_counts = as_tensor(view_counts, logodds.device)
    if tuple(view_counts.shape) != (logodds.shape[0],):
        raise InvariantError(
            f"view_counts has shape {tuple(view_counts.shape)}, expected ({logodds.shape[0]},)",
            source="fusion.view_counts",
        )
    if rho == 0.0:
        return
    base = float(np.float32(logit(prior)))  # the state's starting value, exactly
    rows = max(1, BLOCK_BYTES // max(1, 4 * logodds.shape[1]))
    for start in range(0, logodds.shape[0], rows):
        block = logodds[start : start + rows]
        n = view_counts[start : start + rows].to(torch.float32)
        scale = torch.reciprocal(1.0 + (n - 1.0).clamp_min(0.0) * rho)
        block -= base
        block *= scale[:, None]
        block += base


def probabilities(logodds: np.ndarray) -> np.ndarray:
    """Relevance probabilities `sigmoid(logodds)` as float32, same shape (host arrays)."""
    return expit(logodds).astype(np.float32, copy=False)


def probability_blocks(logodds: np.ndarray, block_bytes: int = BLOCK_BYTES) -> Iterator[np.ndarray]:
    """`probabilities(logodds)` a block of rows at a time: (rows, T) float32, rows in order.

    Elementwise, so the blocks are bit-identical to the whole; the fuse stage writes them out one by
    one (`store.put_array_blocks`), so the (N, T) probabilities never sit in memory beside the
    (N, T) log-odds: at 5M Gaussians x 100 tasks that is 2 GB not allocated.
    """
    rows = max(1, block_bytes // max(1, 4 * logodds.shape[1]))
    for start in range(0, logodds.shape[0], rows):
        yield probabilities(logodds[start : start + rows])
