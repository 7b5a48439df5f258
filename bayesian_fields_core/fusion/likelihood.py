"""The CLIP measurement model: Gaussian likelihoods of a cosine score given relevance.

The paper (Sec. 4.1-4.2) models `p(phi | y=1) = N(mu1, s^2)` and `p(phi | y=0) = N(mu0, s^2)` with a
shared standard deviation; the white noise `epsilon ~ N(0, s_eps^2)` of the measurement model
(Eq. 4) adds its variance. Because both classes share one variance, the Gaussian normalisers
cancel in the likelihood ratio and only the two squared distances remain, which is all the
Bayesian update needs (it works in log-odds).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.params import PAPER_MU0, PAPER_MU1, PAPER_S, PipelineParams


@dataclass(frozen=True)
class LikelihoodParams:
    """Parameters of the two class-conditional score Gaussians.

    mu0: mean cosine score of irrelevant (task, segment) pairs (default: the paper's, `PAPER_MU0`).
    mu1: mean score of relevant pairs (default `PAPER_MU1`).
    s: standard deviation shared by both classes (default `PAPER_S`).
    s_eps: standard deviation of the extra measurement noise epsilon (default 0: the paper folds
        it into `s`); the effective variance is `s^2 + s_eps^2`.
    """

    mu0: float = PAPER_MU0
    mu1: float = PAPER_MU1
    s: float = PAPER_S
    s_eps: float = PipelineParams.model_fields["s_eps"].default

    def __post_init__(self) -> None:
        for name in ("mu0", "mu1", "s", "s_eps"):
            if not np.isfinite(getattr(self, name)):
                raise InputError(f"must be finite, got {getattr(self, name)!r}", source=f"likelihood.{name}")
        if self.s <= 0:
            raise InputError(f"must be > 0, got {self.s}", source="likelihood.s")
        if self.s_eps < 0:
            raise InputError(f"must be >= 0, got {self.s_eps}", source="likelihood.s_eps")

    @property
    def variance(self) -> float:
        """Effective variance `s^2 + s_eps^2` of both class-conditional Gaussians."""
        return self.s**2 + self.s_eps**2


def resolve_likelihood(params: PipelineParams, calibration: object | None) -> LikelihoodParams:
    """The likelihood a run uses: job parameters override the model's calibration, which
    overrides the paper's values. `calibration` is anything with `mu0`, `mu1`, `s` attributes
    (`calibration.model.Calibration`), or None for a model without one."""

    def pick(name: str, paper: float) -> float:
        value = getattr(params, name)
        return float(value) if value is not None else float(getattr(calibration, name, paper))

    return LikelihoodParams(
        mu0=pick("mu0", PAPER_MU0), mu1=pick("mu1", PAPER_MU1), s=pick("s", PAPER_S), s_eps=params.s_eps
    )


def log_likelihood_ratio(phi: np.ndarray, params: LikelihoodParams) -> np.ndarray:
    """`log p(phi|y=1) - log p(phi|y=0)` for every score, as float32 of the same shape.

    Equal variances make the normalisers cancel:
    `llr = ((phi - mu0)^2 - (phi - mu1)^2) / (2 sigma^2)`. Computed in float64 and cast once, so the
    small differences of nearby means are not lost to float32 rounding.
    """
    phi64 = np.asarray(phi, dtype=np.float64)
    llr = ((phi64 - params.mu0) ** 2 - (phi64 - params.mu1) ** 2) / (2.0 * params.variance)
    return llr.astype(np.float32)
