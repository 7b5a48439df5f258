"""One fusion run's per-Gaussian state on one device, fed a frame at a time (METHOD steps 3-5).

What the frames accumulate: the log-odds of the Bayesian update (or the running score sums of
the averaging ablation), each Gaussian's best single view per task (`peak`), and, only when
`view_correlation` asks, each Gaussian's number of accepted views. All of it lives as tensors on
the fusion device; a frame arrives as its (Gaussian, mask) pairs on that device and its masks'
cosine scores on the host, and leaves behind the masks' OR-phi flags on the host (the primitive
builder and the stage's artifacts need them there). `finish` hands the host arrays the fuse stage
writes. The fuse stage owns the rest: caches, rendering, primitives, artifacts and progress.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import torch
from scipy.special import logit

from bayesian_fields_core.fusion.averaging import CosineAverager
from bayesian_fields_core.fusion.bayes import (
    accepted_masks,
    bayes_update,
    count_views,
    discount_correlated_views,
    init_logodds,
)
from bayesian_fields_core.fusion.likelihood import LikelihoodParams, log_likelihood_ratio
from bayesian_fields_core.fusion.peak import init_peak, margin, update_peak
from bayesian_fields_core.fusion.tensors import as_tensor, to_numpy

PROBABILITY_CLIP = 1e-12
"""Averaging's probabilities are clipped to [c, 1 - c] before their log-odds are taken (the
stored log-odds must be finite)."""


@dataclass(frozen=True)
class FusionSettings:
    """How the frames are fused (the `PipelineParams` of the same names; `mode` is `fusion`)."""

    likelihood: LikelihoodParams
    mode: Literal["bayes", "average"]
    prior: float
    outlier_rejection: bool
    view_correlation: float


@dataclass
class FusedArrays:
    """The fusion result on the host, as the fuse stage stores it.

    logodds, peak: (N, T) float32. probabilities: (N, T) float32 for the averaging ablation;
    None for the Bayesian update, whose probabilities are `sigmoid(logodds)`, written a block at a
    time (`bayes.probability_blocks`). observed: (N,) bool, Gaussians some accepted mask saw
    (averaging only, else None). view_counts: (N,) int32 accepted views per Gaussian (the
    Bayesian update only, else None).
    """

    logodds: np.ndarray
    peak: np.ndarray
    probabilities: np.ndarray | None = None
    observed: np.ndarray | None = None
    view_counts: np.ndarray | None = None


class FusionState:
    """The per-Gaussian state of `num_gaussians` Gaussians x `num_tasks` tasks on `device`."""

    def __init__(
        self, num_gaussians: int, num_tasks: int, settings: FusionSettings, device: torch.device | str
    ) -> None:
        self.settings = settings
        self.device = torch.device(device)
        bayes = settings.mode == "bayes"
        self.logodds = init_logodds(num_gaussians, num_tasks, settings.prior, self.device) if bayes else None
        self.averager = None if bayes else CosineAverager(num_gaussians, num_tasks, self.device)
        self.peak = init_peak(num_gaussians, num_tasks, self.device)
        # Accepted views per Gaussian: the correlated-views discount and the per-view conditionals
        # of the clustering (`aib_conditionals`) read them; one scatter per frame.
        self.view_counts = (
            torch.zeros(num_gaussians, dtype=torch.int32, device=self.device) if bayes else None
        )

    def add_frame(self, gaussian_ids: torch.Tensor, mask_ids: torch.Tensor, phi: np.ndarray) -> np.ndarray:
        """Fuse one frame; return its masks' OR-phi flags (M,) bool on the host.

        gaussian_ids (n,) int64 and mask_ids (n,) int32 on the state's device: Gaussian
        `gaussian_ids[k]` is seen through mask `mask_ids[k]` (`visibility.mask_associations`).
        phi: (M, T) float32 cosine scores of the frame's masks against the tasks. Ratios and
        margins are computed from them on the host in float64 (small: M x T) and moved once.
        """
        s = self.settings
        llr = as_tensor(log_likelihood_ratio(phi, s.likelihood), self.device)
        if self.logodds is not None:
            accepted = bayes_update(
                self.logodds, gaussian_ids, mask_ids, llr, outlier_rejection=s.outlier_rejection
            )
        else:
            accepted = accepted_masks(llr, s.outlier_rejection)
            assert self.averager is not None  # exactly one of logodds / averager exists
            self.averager.add_frame(gaussian_ids, mask_ids, phi, accepted)
        margins = as_tensor(margin(phi, s.likelihood.mu0, s.likelihood.mu1), self.device)
        update_peak(self.peak, gaussian_ids, mask_ids, margins, accepted)
        if self.view_counts is not None:
            count_views(self.view_counts, gaussian_ids, mask_ids, accepted)
        return to_numpy(accepted)

    def finish(self) -> FusedArrays:
        """The state after the last frame, on the host (the only host copy of a GPU state)."""
        s = self.settings
        peak = to_numpy(self.peak)
        if self.logodds is not None:
            assert self.view_counts is not None  # counted whenever there are log-odds
            if s.view_correlation > 0:
                discount_correlated_views(self.logodds, self.view_counts, s.view_correlation, s.prior)
            return FusedArrays(
                logodds=to_numpy(self.logodds), peak=peak, view_counts=to_numpy(self.view_counts)
            )
        assert self.averager is not None  # exactly one of logodds / averager exists
        probs = self.averager.probabilities(s.likelihood, unobserved=s.prior)
        clipped = np.clip(probs.astype(np.float64), PROBABILITY_CLIP, 1 - PROBABILITY_CLIP)
        logodds = logit(clipped).astype(np.float32)
        observed = self.averager.host_state()[1] > 0
        return FusedArrays(logodds=logodds, peak=peak, probabilities=probs, observed=observed)
