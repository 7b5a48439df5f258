"""Measurement model and Bayesian update, checked against hand-worked numbers and Eq. 5."""

import math

import numpy as np
import pytest
from scipy.stats import norm

from bayesian_fields_core.errors import InputError, InvariantError
from bayesian_fields_core.fusion.bayes import (
    accepted_masks,
    bayes_update,
    init_logodds,
    probabilities,
)
from bayesian_fields_core.fusion.likelihood import LikelihoodParams, log_likelihood_ratio


def test_llr_hand_values() -> None:
    params = LikelihoodParams()  # mu0 0.20, mu1 0.27, s 0.035
    # At mu1: (0.07^2 - 0) / (2 * 0.035^2) = 0.0049 / 0.00245 = 2; at mu0: -2; midpoint: 0.
    llr = log_likelihood_ratio(np.array([[0.27, 0.20, 0.235]]), params)
    np.testing.assert_allclose(llr, [[2.0, -2.0, 0.0]], atol=1e-6)
    assert llr.dtype == np.float32
    # s_eps = sqrt(3) * s makes the variance 4 s^2, so the ratio shrinks four-fold.
    noisy = LikelihoodParams(s_eps=0.035 * math.sqrt(3.0))
    np.testing.assert_allclose(log_likelihood_ratio(np.array([0.27]), noisy), [0.5], atol=1e-6)


def test_llr_matches_gaussian_densities() -> None:
    params = LikelihoodParams(mu0=0.18, mu1=0.3, s=0.04, s_eps=0.01)
    phi = np.linspace(0.0, 0.5, 11)
    sd = math.sqrt(0.04**2 + 0.01**2)
    expected = norm.logpdf(phi, 0.3, sd) - norm.logpdf(phi, 0.18, sd)
    np.testing.assert_allclose(log_likelihood_ratio(phi, params), expected, rtol=1e-5, atol=1e-5)


def test_invalid_params_raise() -> None:
    with pytest.raises(InputError, match="likelihood.s"):
        LikelihoodParams(s=0.0)
    with pytest.raises(InputError, match="s_eps"):
        LikelihoodParams(s_eps=-1.0)


def test_bayes_step_hand_worked() -> None:
    # Prior 0.05. Observation at phi = mu1 has l1/l0 = e^2 = 7.389056:
    # p = 7.389056 * 0.05 / (7.389056 * 0.05 + 0.95) = 0.3694528 / 1.3194528 = 0.280005.
    logodds = init_logodds(3, 2)
    np.testing.assert_allclose(probabilities(logodds.numpy()), 0.05, rtol=1e-6)
    llr = log_likelihood_ratio(np.array([[0.27, 0.20]]), LikelihoodParams())  # [2, -2]
    accepted = bayes_update(logodds, np.array([1]), np.array([0], dtype=np.int32), llr)
    assert accepted.tolist() == [True]
    p = probabilities(logodds.numpy())
    np.testing.assert_allclose(
        p[1], [0.280005, 0.05 * math.exp(-2) / (0.05 * math.exp(-2) + 0.95)], rtol=1e-5
    )
    np.testing.assert_allclose(p[[0, 2]], 0.05, rtol=1e-6)  # unseen Gaussians untouched
    # The opposite observation (task 0 at mu0, task 1 at mu1) brings Gaussian 1 back to the prior.
    bayes_update(logodds, np.array([1]), np.array([0]), -llr)
    np.testing.assert_allclose(probabilities(logodds.numpy())[1], [0.05, 0.05], rtol=1e-5)


def test_log_odds_equals_probability_space_recursion() -> None:
    rng = np.random.default_rng(0)
    params = LikelihoodParams()
    scores = rng.normal(0.24, 0.04, size=(40, 3))
    logodds = init_logodds(1, 3)
    p = np.full(3, 0.05)
    for phi in scores:
        bayes_update(
            logodds,
            np.array([0]),
            np.array([0]),
            log_likelihood_ratio(phi[None], params),
            outlier_rejection=False,
        )
        l1 = norm.pdf(phi, params.mu1, params.s)
        l0 = norm.pdf(phi, params.mu0, params.s)
        p = l1 * p / (l1 * p + l0 * (1 - p))  # Eq. 5 of METHOD.md
    np.testing.assert_allclose(probabilities(logodds.numpy())[0], p, rtol=2e-4, atol=1e-6)


def test_or_phi_rejects_masks_lowering_every_task() -> None:
    llr = np.array([[-1.0, -0.5], [-1.0, 0.5], [0.0, -3.0]], dtype=np.float32)
    # Mask 0 lowers both tasks: rejected. Mask 1 raises task 1; mask 2 leaves task 0 unchanged.
    assert accepted_masks(llr).tolist() == [False, True, True]
    assert accepted_masks(llr, outlier_rejection=False).tolist() == [True, True, True]

    logodds = init_logodds(3, 2)
    before = logodds.clone()
    gids, mids = np.array([0, 1, 2]), np.array([0, 1, 2])
    accepted = bayes_update(logodds, gids, mids, llr)
    assert accepted.tolist() == [False, True, True]
    np.testing.assert_array_equal(logodds[0].numpy(), before[0].numpy())
    np.testing.assert_allclose((logodds[1:] - before[1:]).numpy(), llr[1:])

    plain = init_logodds(3, 2)
    bayes_update(plain, gids, mids, llr, outlier_rejection=False)
    np.testing.assert_allclose((plain - before).numpy(), llr)


def test_bayes_update_validates_shapes() -> None:
    """Disagreeing shapes between stages are a broken invariant (a bug), not bad input; a bad
    parameter value is bad input."""
    logodds = init_logodds(2, 2)
    with pytest.raises(InvariantError, match="llr") as caught:
        bayes_update(logodds, np.array([0]), np.array([0]), np.zeros((1, 3), dtype=np.float32))
    assert not isinstance(caught.value, InputError)
    with pytest.raises(InvariantError, match="mask_ids"):
        bayes_update(logodds, np.array([0]), np.array([4]), np.zeros((1, 2), dtype=np.float32))
    with pytest.raises(InputError, match="prior"):
        init_logodds(2, 2, prior=1.0)
