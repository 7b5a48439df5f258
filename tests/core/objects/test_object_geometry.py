"""object_geometry: sizes, centroids and boxes per object, including the edge cases a real
scene reaches (no object survives the filters; an object emptied by the kNN filter)."""

from __future__ import annotations

import numpy as np

from bayesian_fields_core.objects.clustering import object_geometry


def test_no_objects_gives_empty_float_centroids() -> None:
    means = np.random.default_rng(0).normal(size=(50, 3)).astype(np.float32)
    object_ids = np.full(50, -1)
    sizes, centroids, boxes = object_geometry(means, object_ids, np.array([], dtype=np.int64), 0)
    assert sizes.shape == (0,)
    assert centroids.shape == (0, 3) and centroids.dtype == np.float64
    assert boxes == []


def test_centroids_are_member_means_and_only_selected_objects_get_boxes() -> None:
    rng = np.random.default_rng(1)
    means = rng.normal(size=(40, 3)).astype(np.float32)
    object_ids = np.repeat(np.arange(4), 10)
    object_ids[30:] = -1  # object 3 lost every member
    sizes, centroids, boxes = object_geometry(means, object_ids, np.array([0, 2, 3]), 4)
    assert sizes.tolist() == [10, 10, 10, 0]
    for k in range(3):
        np.testing.assert_allclose(centroids[k], means[object_ids == k].mean(axis=0), rtol=1e-5, atol=1e-6)
    np.testing.assert_array_equal(centroids[3], 0.0)
    assert boxes[0] is not None and boxes[2] is not None
    assert boxes[1] is None and boxes[3] is None
