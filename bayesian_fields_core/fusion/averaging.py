"""The "no Bayesian updating" ablation (paper Sec. 8, column BU): average the cosine scores.

Instead of fusing frames recursively, each Gaussian accumulates the cosine scores of the masks it
was seen through; at the end the mean score goes through Eq. 3 of the paper once,
`p(y=1|phi) = p(phi|y=1) p(y=1) / (p(phi|y=0) p(y=0) + p(phi|y=1) p(y=1))`, with the paper's
uninformative prior `p(y=1) = p(y=0) = 1/2`. In log-odds that is
`sigmoid(llr(mean phi) + logit(eq3_prior))`. The paper notes OR-phi can still run here (the
probability is computed to decide it), so the caller passes the `accepted` flags of
`bayes.accepted_masks` and rejected masks contribute no score.
"""

from __future__ import annotations

import numpy as np
from scipy.special import expit, logit

from bayesian_fields_core.errors import InputError, InvariantError
from bayesian_fields_core.fusion.likelihood import LikelihoodParams, log_likelihood_ratio
from bayesian_fields_core.params import default

EQ3_PRIOR = 0.5
"""Prior of Eq. 3: the paper sets p(y=1) = p(y=0) (uninformative)."""


class CosineAverager:
    """Running per-Gaussian sums of cosine scores (N, T) and observation counts (N,)."""

    def __init__(self, num_gaussians: int, num_tasks: int) -> None:
        # float64 sums: hundreds of frames of scores near 0.2 would drift in float32.
        self.sums = np.zeros((num_gaussians, num_tasks), dtype=np.float64)
        self.counts = np.zeros(num_gaussians, dtype=np.int64)

    def add_frame(
        self,
        gaussian_ids: np.ndarray,
        mask_ids: np.ndarray,
        phi: np.ndarray,
        accepted: np.ndarray | None = None,
    ) -> None:
        """Add the scores `phi` (M, T) of the masks each Gaussian is seen through this frame.

        Gaussians occur at most once per frame (exclusive masks), so fancy-index `+=` is exact.
        """
        if phi.ndim != 2 or phi.shape[1] != self.sums.shape[1]:
            raise InvariantError(
                f"expected (M, {self.sums.shape[1]}), got {phi.shape}", source="averaging.phi"
            )
        if gaussian_ids.shape != mask_ids.shape:
            raise InvariantError("gaussian_ids and mask_ids differ in shape", source="averaging.associations")
        if accepted is not None:
            keep = np.asarray(accepted, dtype=bool)[mask_ids]
            gaussian_ids, mask_ids = gaussian_ids[keep], mask_ids[keep]
        self.sums[gaussian_ids] += phi[mask_ids]
        self.counts[gaussian_ids] += 1

    def mean_scores(self) -> np.ndarray:
        """(N, T) mean cosine score; NaN for Gaussians never observed."""
        with np.errstate(invalid="ignore", divide="ignore"):
            return self.sums / self.counts[:, None]

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
        seen = self.counts > 0
        out = np.full(self.sums.shape, unobserved, dtype=np.float32)
        mean = self.sums[seen] / self.counts[seen, None]
        out[seen] = expit(log_likelihood_ratio(mean, params).astype(np.float64) + logit(eq3_prior))
        return out
