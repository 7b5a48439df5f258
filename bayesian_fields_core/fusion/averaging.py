"""The "no Bayesian updating" ablation (paper Sec. 8, column BU): average the cosine scores.

Instead of fusing frames recursively, each Gaussian accumulates the cosine scores of the masks it
was seen through; at the end the mean score goes through Eq. 3 of the paper once,
`p(y=1|phi) = p(phi|y=1) p(y=1) / (p(phi|y=0) p(y=0) + p(phi|y=1) p(y=1))`, with the paper's
uninformative prior `p(y=1) = p(y=0) = 1/2`. In log-odds that is
`sigmoid(llr(mean phi) + logit(eq3_prior))`. The paper notes OR-phi can still run here (the
probability is computed to decide it), so the caller passes the `accepted` flags of
`bayes.accepted_masks` and rejected masks contribute no score.

The running sums live on the fusion device (torch ops, like the log-odds); Eq. 3 runs once, on
the host copy, with the likelihood's float64 arithmetic.
"""

from __future__ import annotations

import numpy as np
import torch
from scipy.special import expit, logit

from bayesian_fields_core.errors import InputError, InvariantError
from bayesian_fields_core.fusion.bayes import accepted_pairs
from bayesian_fields_core.fusion.likelihood import LikelihoodParams, log_likelihood_ratio
from bayesian_fields_core.fusion.tensors import as_tensor, to_numpy
from bayesian_fields_core.params import default

EQ3_PRIOR = 0.5
"""Prior of Eq. 3: the paper sets p(y=1) = p(y=0) (uninformative)."""


class CosineAverager:
    """Running per-Gaussian sums of cosine scores (N, T) and observation counts (N,), as tensors
    on `device` (the fusion device: the same ops on the CPU and a GPU worker).

    float64 sums: hundreds of frames of scores near 0.2 would drift in float32. Each frame adds one
    float32 score to an element at most once (exclusive masks), so the sums do not depend on the
    device or on the order of the pairs.
    """

    def __init__(self, num_gaussians: int, num_tasks: int, device: torch.device | str = "cpu") -> None:
        self.sums = torch.zeros((num_gaussians, num_tasks), dtype=torch.float64, device=device)
        self.counts = torch.zeros(num_gaussians, dtype=torch.int64, device=device)

    def add_frame(
        self,
        gaussian_ids: np.ndarray | torch.Tensor,
        mask_ids: np.ndarray | torch.Tensor,
        phi: np.ndarray | torch.Tensor,
        accepted: np.ndarray | torch.Tensor | None = None,
    ) -> None:
        """Add the scores `phi` (M, T) of the masks each Gaussian is seen through this frame;
        `accepted` (M,) leaves out the masks OR-phi rejected. Inputs move to the state's device."""
        device = self.sums.device
        phi = as_tensor(phi, device, torch.float32)
        if phi.ndim != 2 or phi.shape[1] != self.sums.shape[1]:
            raise InvariantError(
                f"expected (M, {self.sums.shape[1]}), got {tuple(phi.shape)}", source="averaging.phi"
            )
        gaussian_ids, mask_ids = as_tensor(gaussian_ids, device), as_tensor(mask_ids, device)
        if gaussian_ids.shape != mask_ids.shape:
            raise InvariantError("gaussian_ids and mask_ids differ in shape", source="averaging.associations")
        if accepted is None:
            accepted = torch.ones(phi.shape[0], dtype=torch.bool, device=device)
        rows, masks = accepted_pairs(gaussian_ids, mask_ids, as_tensor(accepted, device, torch.bool))
        self.sums.index_add_(0, rows, phi[masks].to(torch.float64))
        self.counts[rows] += 1

    def host_state(self) -> tuple[np.ndarray, np.ndarray]:
        """(sums (N, T) float64, counts (N,) int64) as host arrays (views on the CPU)."""
        return to_numpy(self.sums), to_numpy(self.counts)

    def mean_scores(self) -> np.ndarray:
        """(N, T) mean cosine score on the host; NaN for Gaussians never observed."""
        sums, counts = self.host_state()
        with np.errstate(invalid="ignore", divide="ignore"):
            return sums / counts[:, None]

    def probabilities(
        self,
        params: LikelihoodParams,
        *,
        eq3_prior: float = EQ3_PRIOR,
        unobserved: float = default("prior"),
    ) -> np.ndarray:
        """(N, T) float32: Eq. 3 applied to the mean score.

        `unobserved` is the probability given to Gaussians no accepted mask ever saw; the default
        is the Bayesian prior 0.05 so both fusion modes leave unseen Gaussians alike.
        """
        for name, value in (("eq3_prior", eq3_prior), ("unobserved", unobserved)):
            if not 0.0 < value < 1.0:
                raise InputError(f"must be in (0, 1), got {value}", source=f"averaging.{name}")
        sums, counts = self.host_state()
        seen = counts > 0
        out = np.full(sums.shape, unobserved, dtype=np.float32)
        mean = sums[seen] / counts[seen, None]
        out[seen] = expit(log_likelihood_ratio(mean, params).astype(np.float64) + logit(eq3_prior))
        return out
