"""`view_correlation`: the Bayesian update with equicorrelated view errors (a deviation from the
paper's independent views, off by default)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import logit

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.fusion.bayes import bayes_update, discount_correlated_views, init_logodds
from bayesian_fields_core.fusion.likelihood import LikelihoodParams, log_likelihood_ratio

LIK = LikelihoodParams(mu0=0.0, mu1=0.6, s=0.2)


def _fused(scores: np.ndarray, rho: float, prior: float = 0.05) -> float:
    """One Gaussian, one task, seen in len(scores) views, through the stage's functions (OR-phi off:
    with one task it would drop every view below the midpoint)."""
    logodds = init_logodds(1, 1, prior)
    for phi in scores:
        llr = log_likelihood_ratio(np.array([[phi]]), LIK)
        bayes_update(logodds, np.array([0]), np.array([0]), llr, outlier_rejection=False)
    discount_correlated_views(logodds, np.array([len(scores)], dtype=np.int32), rho, prior)
    return float(logodds[0, 0])


@pytest.mark.parametrize("rho", [0.0, 0.2, 0.7])
def test_equals_the_equicorrelated_gaussian_likelihood_ratio(rho: float) -> None:
    """log N(x; mu1 1, S) - log N(x; mu0 1, S) with S = s^2 ((1 - rho) I + rho 11^T), by linear algebra."""
    rng = np.random.default_rng(3)
    x = rng.normal(0.4, 0.2, 7)
    n = len(x)
    cov = LIK.s**2 * ((1 - rho) * np.eye(n) + rho * np.ones((n, n)))
    inv = np.linalg.inv(cov)

    def log_density(mu: float) -> float:
        d = x - mu
        return -0.5 * float(d @ inv @ d)

    expected = logit(0.05) + log_density(LIK.mu1) - log_density(LIK.mu0)
    assert _fused(x, rho) == pytest.approx(expected, rel=1e-4, abs=1e-4)


def test_many_agreeing_views_stop_adding_evidence() -> None:
    """A confusion repeated in 30 views no longer outranks a right object seen in 8 with higher scores."""
    confusion, right = np.full(30, 0.45), np.full(8, 0.55)
    assert _fused(confusion, 0.0) > _fused(right, 0.0)  # the paper's update: count wins
    assert _fused(confusion, 0.3) < _fused(right, 0.3)  # correlated views: the score wins
    assert _fused(np.full(50, 0.45), 1.0) == pytest.approx(_fused(np.full(1, 0.45), 0.0), abs=1e-4)


def test_unseen_gaussians_keep_the_prior_and_bad_rho_is_refused() -> None:
    logodds = init_logodds(2, 3)
    logodds[1] += 4.0
    discount_correlated_views(logodds, np.array([0, 5], dtype=np.int32), 0.5)
    assert np.allclose(logodds[0].numpy(), logit(0.05))
    assert np.allclose(logodds[1].numpy(), logit(0.05) + 4.0 / 3.0)
    with pytest.raises(InputError, match="view_correlation"):
        discount_correlated_views(logodds, np.array([0, 5], dtype=np.int32), 1.5)
