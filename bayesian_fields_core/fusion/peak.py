"""Peak evidence: the best single view of each Gaussian for each task, for "not found" answers.

The fused log-odds add up every view, so a task that names something the scene does not hold
("pick up the red lamp") still collects positive evidence on the object that resembles it most
(a lamp of another colour) when CLIP scores that object a little above the irrelevant mean in
many views, and its probability saturates near 1 (the sample's purple cone: p = 0.955). What
separates such a task from a present one on the synthetic suite is the *best* view: the
strongest single mask score any view gave the object (eval/not_found.py measures it). We keep,
per Gaussian and task, the highest cosine score of an accepted mask that contains it, expressed
as a *margin* `(phi - mu0) / (mu1 - mu0)` of the calibrated likelihoods: 0 at the irrelevant
mean, 1 at the relevant mean, so one threshold means the same for every calibrated CLIP.

Masks are exclusive, so a Gaussian occurs at most once per frame and a fancy-indexed maximum is
exact (the same argument as `bayes.bayes_update`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

UNSEEN = -1e9
"""Margin of a Gaussian no accepted mask ever contained (far below any threshold)."""


def margin(phi: np.ndarray, mu0: float, mu1: float) -> np.ndarray:
    """(M, T) cosine scores -> float32 margins `(phi - mu0) / (mu1 - mu0)`."""
    return ((np.asarray(phi, dtype=np.float64) - mu0) / (mu1 - mu0)).astype(np.float32)


def init_peak(num_gaussians: int, num_tasks: int) -> np.ndarray:
    """A fresh (N, T) float32 peak-margin state: every Gaussian unseen."""
    return np.full((num_gaussians, num_tasks), UNSEEN, dtype=np.float32)


def update_peak(
    peak: np.ndarray,
    gaussian_ids: np.ndarray,
    mask_ids: np.ndarray,
    margins: np.ndarray,
    accepted: np.ndarray,
) -> None:
    """Raise `peak` (N, T) in place to the margins (M, T) of the accepted masks (M,) that contain
    each Gaussian (`gaussian_ids[k]` seen through `mask_ids[k]`, each Gaussian once per frame)."""
    if mask_ids.size == 0:
        return
    keep = np.asarray(accepted, dtype=bool)[mask_ids]
    g = gaussian_ids[keep]
    peak[g] = np.maximum(peak[g], margins[mask_ids[keep]])


def init_peak_torch(num_gaussians: int, num_tasks: int, device: Any) -> Any:
    import torch

    return torch.full((num_gaussians, num_tasks), UNSEEN, dtype=torch.float32, device=device)


def update_peak_torch(peak: Any, gaussian_ids: Any, mask_ids: Any, margins: Any, accepted: Any) -> None:
    """`update_peak` on the device (tensors; `mask_ids` any integer dtype)."""
    import torch

    if mask_ids.numel() == 0:
        return
    mids = mask_ids.long()
    keep = accepted[mids]
    g = gaussian_ids[keep].long()
    peak[g] = torch.maximum(peak[g], margins[mids[keep]])


def object_peak(peak: np.ndarray, members: np.ndarray, task: int) -> float:
    """An object's peak margin for one task: the median over its Gaussians (`members`, indices)
    of their best view, robust to a few border Gaussians that a neighbour's mask also covered."""
    values = peak[members, task]
    return float(np.median(values)) if values.size else UNSEEN
