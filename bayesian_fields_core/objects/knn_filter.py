"""Floater removal: statistical outlier filtering of an object's Gaussian centres (paper Sec. 5).

Like Open3D's `remove_statistical_outlier`: each point's mean distance to its `k` nearest
neighbours is compared with the mean `m` and standard deviation `s` of that quantity over the
object; points with a mean distance above `m + std_ratio * s` are floaters. Differences from
Open3D, on purpose: the point itself is not counted among its neighbours (Open3D's kNN includes
it at distance 0, so its "k" is k-1 real neighbours), and exact duplicates (mean distance 0) are
kept rather than dropped.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.params import default


def mean_neighbour_distance(points: np.ndarray, k: int = default("knn_k")) -> np.ndarray:
    """(n,) mean Euclidean distance of each point to its `min(k, n-1)` nearest other points."""
    n = points.shape[0]
    k_eff = min(k, n - 1)
    if k_eff < 1:
        return np.zeros(n)
    distances, _ = cKDTree(points).query(points, k=k_eff + 1)
    return np.asarray(distances)[:, 1:].mean(axis=1)


def statistical_outlier_mask(
    points: np.ndarray, k: int = default("knn_k"), std_ratio: float = default("knn_std_ratio")
) -> np.ndarray:
    """(n,) bool keep-mask: mean kNN distance `<= mean + std_ratio * std` over the points.

    With fewer than 3 points there is no meaningful spread and everything is kept; with
    `n <= k`, all other points are the neighbours.
    """
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise InputError(f"expected (n, 3), got {points.shape}", source="knn_filter.points")
    if k < 1 or std_ratio < 0:
        raise InputError(f"need k >= 1 and std_ratio >= 0, got {k}, {std_ratio}", source="knn_filter")
    n = points.shape[0]
    if n < 3:
        return np.ones(n, dtype=bool)
    avg = mean_neighbour_distance(points, k)
    threshold = avg.mean() + std_ratio * avg.std(ddof=1)
    return avg <= threshold
