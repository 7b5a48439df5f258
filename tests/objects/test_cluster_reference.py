"""The clustering gives the same partition as the reference implementation.

`fixtures/cluster_reference.npz` was computed by the clustering code as it stood before the
speed-ups of issue 11 item 7 (commit 5ccfefe) on the seeded scene of `cluster_scene.py`: the
primitive and object of every Gaussian, the selected objects per task, object sizes and the
selected objects' boxes. Any change to the primitive rule, the graph, the AIB, pruning, selection,
the kNN filter or the boxes that alters an outcome fails here.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bayesian_fields_core.objects.clustering import objects_from_primitives, primitive_scores
from bayesian_fields_core.objects.primitives import PrimitiveBuilder
from bayesian_fields_core.params import PipelineParams

from .cluster_scene import cluster_scene

REFERENCE = Path(__file__).parent / "fixtures" / "cluster_reference.npz"


@pytest.fixture(scope="module")
def clustered():
    means, frames, probabilities = cluster_scene()
    builder = PrimitiveBuilder(len(means))
    for gaussian_ids, mask_ids, accepted in frames:
        builder.add_frame(gaussian_ids, mask_ids, accepted)
    primitive_ids = builder.primitive_ids
    logodds = np.log(probabilities / (1 - probabilities)).astype(np.float32)
    params = PipelineParams()
    scores = primitive_scores(primitive_ids, probabilities, logodds, params)
    object_map = objects_from_primitives(
        means, primitive_ids, scores.pyx, params, scores.relevance, scores.evidence
    )
    return primitive_ids, object_map


def test_partition_and_selection_match_the_reference(clustered) -> None:
    primitive_ids, object_map = clustered
    ref = np.load(REFERENCE, allow_pickle=False)
    assert object_map.counts["nodes_after_identical_merge"] < object_map.counts["primitives"]  # merges ran
    assert object_map.counts["knn_removed_gaussians"] > 0  # the floater filter ran
    np.testing.assert_array_equal(primitive_ids, ref["primitive_ids"])
    np.testing.assert_array_equal(object_map.object_ids, ref["object_ids"])
    np.testing.assert_array_equal(object_map.selection, ref["selection"])
    np.testing.assert_array_equal(object_map.sizes, ref["sizes"])
    counts = np.array([object_map.counts[k] for k in sorted(object_map.counts)])
    np.testing.assert_array_equal(counts, ref["counts"])


def test_boxes_match_the_reference(clustered) -> None:
    _, object_map = clustered
    ref = np.load(REFERENCE, allow_pickle=False)
    chosen = np.unique(object_map.selection[object_map.selection >= 0])
    boxes = [object_map.boxes[o] for o in chosen]
    assert all(box is not None for box in boxes)
    np.testing.assert_allclose([b.center for b in boxes], ref["box_centres"], atol=1e-9)
    np.testing.assert_allclose([b.extents for b in boxes], ref["box_extents"], atol=1e-9)
    np.testing.assert_allclose([b.rotation for b in boxes], ref["box_rotations"], atol=1e-9)
