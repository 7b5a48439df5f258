"""fusion.peak: each Gaussian keeps its best accepted view per task, as a likelihood margin; an
object's peak is the median over its Gaussians (what the "not found" rule thresholds)."""

from __future__ import annotations

import numpy as np
import pytest

from bayesian_fields_core.fusion.peak import UNSEEN, init_peak, margin, object_peak, update_peak


def test_margin_is_zero_at_mu0_and_one_at_mu1() -> None:
    np.testing.assert_allclose(margin(np.array([[0.2, 0.3, 0.25]]), 0.2, 0.3), [[0.0, 1.0, 0.5]], atol=1e-6)


def test_peak_keeps_the_best_accepted_view_only() -> None:
    peak = init_peak(4, 2)
    # Frame 1: mask 0 holds Gaussians 0, 1; mask 1 (rejected) holds Gaussian 2.
    update_peak(
        peak,
        np.array([0, 1, 2]),
        np.array([0, 0, 1]),
        np.array([[0.5, 0.1], [9.0, 9.0]]),
        np.array([True, False]),
    )
    # Frame 2: a weaker view of Gaussian 0, a stronger one of Gaussian 1.
    update_peak(
        peak, np.array([0, 1]), np.array([0, 1]), np.array([[0.2, 0.0], [0.8, 0.3]]), np.array([True, True])
    )
    update_peak(peak, np.zeros(0, int), np.zeros(0, int), np.zeros((0, 2)), np.zeros(0, bool))  # empty frame
    stored = peak.numpy()  # what the fuse stage writes and the cluster stage reads
    np.testing.assert_allclose(stored[0], [0.5, 0.1])
    np.testing.assert_allclose(stored[1], [0.8, 0.3])
    assert (stored[2] == UNSEEN).all() and (stored[3] == UNSEEN).all()  # rejected mask / never seen
    assert object_peak(stored, np.array([0, 1, 3]), 0) == pytest.approx(0.5)  # median, robust to one unseen
    assert object_peak(stored, np.zeros(0, int), 0) == UNSEEN
