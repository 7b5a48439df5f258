"""The averaging ablation (Eq. 3 on the mean score) and score calibration files."""

import math

import numpy as np
import pytest

from bayesian_fields_core.calibration.model import (
    Calibration,
    fit_calibration,
    load_calibration,
    save_calibration,
)
from bayesian_fields_core.errors import InputError
from bayesian_fields_core.fusion.averaging import CosineAverager
from bayesian_fields_core.fusion.bayes import accepted_masks
from bayesian_fields_core.fusion.likelihood import LikelihoodParams, log_likelihood_ratio


def test_average_then_eq3() -> None:
    params = LikelihoodParams()
    avg = CosineAverager(num_gaussians=3, num_tasks=2)
    # Gaussian 0 is seen at task-0 scores 0.25 and 0.29 (mean 0.27 = mu1 -> llr 2) and task-1
    # scores 0.20, 0.20 (llr -2). With the Eq. 3 prior 1/2: p = sigmoid(2), sigmoid(-2).
    frames = [np.array([[0.25, 0.20]]), np.array([[0.29, 0.20]])]
    for phi in frames:
        avg.add_frame(np.array([0]), np.array([0]), phi, accepted_masks(log_likelihood_ratio(phi, params)))
    # A rejected mask (both scores at mu0) contributes nothing to Gaussian 1.
    bad = np.array([[0.20, 0.20]])
    avg.add_frame(np.array([1]), np.array([0]), bad, accepted_masks(log_likelihood_ratio(bad, params)))
    p = avg.probabilities(params)
    sig = 1.0 / (1.0 + math.exp(-2.0))
    np.testing.assert_allclose(p[0], [sig, 1.0 - sig], rtol=1e-5)
    np.testing.assert_allclose(p[1:], 0.05)  # never (acceptedly) observed: the unobserved default
    assert avg.counts.tolist() == [2, 0, 0]
    np.testing.assert_allclose(avg.mean_scores()[0], [0.27, 0.20])


def test_fit_calibration_modes() -> None:
    pos, neg = np.array([0.25, 0.29]), np.array([0.19, 0.21])
    cal = fit_calibration(pos, neg, "clip-x")
    assert (cal.mu0, cal.mu1) == pytest.approx((0.20, 0.27))
    assert cal.s == pytest.approx(math.sqrt(0.0008))  # positives' sample std
    assert fit_calibration(pos, neg, "clip-x", spread="negative").s == pytest.approx(math.sqrt(0.0002))
    # pooled: (0.0008 + 0.0002) / (2 + 2 - 2)
    assert fit_calibration(pos, neg, "clip-x", spread="pooled").s == pytest.approx(math.sqrt(0.0005))
    lp = cal.to_likelihood_params(s_eps=0.01)
    assert lp.variance == pytest.approx(0.0008 + 0.0001)


def test_fit_rejects_bad_scores() -> None:
    with pytest.raises(InputError, match="mu1"):
        fit_calibration(np.array([0.1, 0.12]), np.array([0.2, 0.22]), "m")
    with pytest.raises(InputError, match="positive_scores"):
        fit_calibration(np.array([0.3]), np.array([0.2, 0.22]), "m")


def test_calibration_roundtrip(tmp_path) -> None:
    cal = Calibration(model_id="tiny-clip", mu0=0.2, mu1=0.27, s=0.035)
    path = tmp_path / "cal.json"
    save_calibration(path, cal)
    assert load_calibration(path, model_id="tiny-clip") == cal
    with pytest.raises(InputError, match="not 'other'"):
        load_calibration(path, model_id="other")
    path.write_text('{"model_id": "m", "mu0": 0.3, "mu1": 0.2, "s": 0.03}')
    with pytest.raises(InputError, match="cal.json"):
        load_calibration(path)
    with pytest.raises(InputError, match="not found"):
        load_calibration(tmp_path / "missing.json")
