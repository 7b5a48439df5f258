"""Pruning, top-k selection and the statistical outlier filter."""

import numpy as np
import pytest

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.objects.knn_filter import statistical_outlier_mask
from bayesian_fields_core.objects.select import object_probabilities, prune_mask, top_k


def test_object_probabilities_are_mass_weighted() -> None:
    pyx = np.array([[0.2, 0.8], [0.6, 0.4], [1.0, 0.0]])
    np.testing.assert_allclose(object_probabilities(pyx, np.array([0, 0, 1])), [[0.4, 0.6], [1.0, 0.0]])
    weighted = object_probabilities(pyx, np.array([0, 0, 1]), mass=np.array([3.0, 1.0, 1.0]))
    np.testing.assert_allclose(weighted[0], [0.3, 0.7])


def test_prune_uses_task_columns_only() -> None:
    pyx = np.array([[0.05, 0.05, 0.9], [0.1, 0.0, 0.9], [0.3, 0.2, 0.5], [0.09, 0.09, 0.82]])
    assert prune_mask(pyx).tolist() == [False, True, True, False]


def test_top_k_ties_by_size_and_padding() -> None:
    pyx = np.array([[0.4, 0.1, 0.5], [0.4, 0.3, 0.3], [0.2, 0.3, 0.5], [0.1, 0.05, 0.85]])
    sizes = np.array([10, 50, 5, 7])
    got = top_k(pyx, sizes, k=2)
    # Task 0: objects 0 and 1 tie at 0.4; 1 is larger. Task 1: 1 and 2 tie at 0.3; 1 is larger.
    assert got.tolist() == [[1, 0], [1, 2]]
    keep = np.array([False, False, True, True])
    assert top_k(pyx, sizes, k=3, candidates=keep).tolist() == [[2, 3, -1], [2, 3, -1]]
    with pytest.raises(InputError, match="select.k"):
        top_k(pyx, sizes, k=0)


def test_knn_removes_planted_outliers() -> None:
    rng = np.random.default_rng(0)
    inliers = rng.normal(0.0, 0.05, size=(500, 3))
    outliers = np.array([[1.0, 1.0, 1.0], [-1.0, 0.5, 0.0], [0.0, 0.0, 2.0]])
    keep = statistical_outlier_mask(np.vstack([inliers, outliers]))
    assert not keep[-3:].any()
    assert keep[:-3].mean() > 0.95


def test_knn_small_sets() -> None:
    # n <= k: the other points are all the neighbours; the far point still goes.
    pts = np.array([[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0], [0.1, 0.1, 0], [0.05, 0.05, 0], [5, 5, 5]], float)
    assert statistical_outlier_mask(pts, k=20, std_ratio=1.0).tolist() == [True] * 5 + [False]
    assert statistical_outlier_mask(pts[:2]).tolist() == [True, True]
    assert statistical_outlier_mask(np.zeros((0, 3))).shape == (0,)
    with pytest.raises(InputError, match="knn_filter.points"):
        statistical_outlier_mask(np.zeros((4, 2)))
