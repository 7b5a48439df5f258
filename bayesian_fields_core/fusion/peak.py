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
exact (the same argument as `bayes.bayes_update`). The (N, T) state is a tensor on the fusion
device (torch ops, as the log-odds); the per-mask margins are computed on the host in float64
like the likelihood ratios, and `object_peak` reads the stored host copy.
"""

from __future__ import annotations

import numpy as np
import torch

from bayesian_fields_core.fusion.bayes import accepted_pairs
from bayesian_fields_core.fusion.tensors import as_tensor

UNSEEN = -1e9
"""Margin of a Gaussian no accepted mask ever contained (far below any threshold)."""


def margin(phi: np.ndarray, mu0: float, mu1: float) -> np.ndarray:
    """(M, T) cosine scores -> float32 margins `(phi - mu0) / (mu1 - mu0)`."""
    return ((np.asarray(phi, dtype=np.float64) - mu0) / (mu1 - mu0)).astype(np.float32)


def init_peak(num_gaussians: int, num_tasks: int, device: torch.device | str = "cpu") -> torch.Tensor:
    """A fresh (N, T) float32 peak-margin state on `device`: every Gaussian unseen."""
    return torch.full((num_gaussians, num_tasks), UNSEEN, dtype=torch.float32, device=device)


def update_peak(
    peak: torch.Tensor,
    gaussian_ids: np.ndarray | torch.Tensor,
    mask_ids: np.ndarray | torch.Tensor,
    margins: np.ndarray | torch.Tensor,
    accepted: np.ndarray | torch.Tensor,
) -> None:
    """Raise `peak` (N, T) in place to the margins (M, T) of the accepted masks (M,) that contain
    each Gaussian (`gaussian_ids[k]` seen through `mask_ids[k]`, each Gaussian once per frame).
    Inputs are moved to the state's device; `mask_ids` may be of any integer type."""
    device = peak.device
    rows, masks = accepted_pairs(
        as_tensor(gaussian_ids, device), as_tensor(mask_ids, device), as_tensor(accepted, device, torch.bool)
    )
    peak[rows] = torch.maximum(peak[rows], as_tensor(margins, device, torch.float32)[masks])


def object_peak(peak: np.ndarray, members: np.ndarray, task: int) -> float:
    """An object's peak margin for one task: the median over its Gaussians (`members`, indices)
    of their best view, robust to a few border Gaussians that a neighbour's mask also covered."""
    values = peak[members, task]
    return float(np.median(values)) if values.size else UNSEEN
