"""How the cluster stage ranks a task's objects: relevance, evidence, conditional, min size."""

from __future__ import annotations

import numpy as np

from bayesian_fields_core.objects.clustering import _cluster_mean_operator, objects_from_primitives
from bayesian_fields_core.objects.probabilities import primitive_probabilities, primitive_relevance
from bayesian_fields_core.params import PipelineParams
from bayesian_fields_core.scene.scale import scene_lengths

# Three far-apart primitives (no box overlaps, so the AIB merges nothing):
#  A: 100 Gaussians relevant to both tasks (p = 0.99, 0.99)
#  B:  60 Gaussians relevant to task 0 only (p = 0.90, 0.01)
#  C:  10 Gaussians, a sliver that saturated on task 0 (p = 1.0 - 1e-6, 0.01)
SIZES = (100, 60, 10)
LENGTHS = scene_lengths(PipelineParams(), lambda: 1.0)
"""The run's lengths at scale 1 (no edge padding by default): selection never reads them."""
PROBS = ((0.99, 0.99), (0.90, 0.01), (1.0 - 1e-6, 0.01))


def _scene() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(0)
    ids = np.repeat(np.arange(3), SIZES)
    means = rng.normal(scale=0.05, size=(len(ids), 3)) + np.array([[0, 0, 0], [5, 0, 0], [0, 5, 0]])[ids]
    probs = np.asarray(PROBS, dtype=np.float64)[ids]
    return means, ids, probs


def _select(params: PipelineParams, **scores: np.ndarray) -> list[int]:
    means, ids, probs = _scene()
    pyx = primitive_probabilities(ids, probs)
    object_map = objects_from_primitives(means, ids, pyx, params, **scores, lengths=LENGTHS)
    assert object_map.counts["objects"] == 3
    # Objects keep the primitives' order here (nothing merged or pruned), so ids compare directly.
    return [int(o) for o in object_map.selection[0] if o >= 0]


def test_conditional_penalises_the_object_relevant_to_two_tasks() -> None:
    # Normalised over tasks + null, A's mass is split between its two tasks: ~0.5 < B's ~0.9.
    order = _select(
        PipelineParams(knn_filter=False, top_k=3, selection_score="conditional", min_object_gaussians=1)
    )
    assert order[:2] == [2, 1] and order[2] == 0


def test_relevance_ranks_by_the_task_probability_and_skips_slivers() -> None:
    means, ids, probs = _scene()
    relevance, counts = primitive_relevance(ids, probs)
    np.testing.assert_allclose(relevance, np.asarray(PROBS))
    np.testing.assert_array_equal(counts, SIZES)
    params = PipelineParams(knn_filter=False, top_k=3, min_object_gaussians=1)
    assert _select(params, relevance=relevance) == [2, 0, 1]  # the sliver's 1.0 wins without a floor
    params = PipelineParams(knn_filter=False, top_k=3, min_object_gaussians=50)
    assert _select(params, relevance=relevance) == [0, 1]  # C (10 Gaussians) is never selected


def test_evidence_orders_saturated_objects_by_their_log_odds() -> None:
    means, ids, _ = _scene()
    # Both objects saturate at p = 1.0 in float32, but A carries far more evidence than B.
    logodds = np.array([[40.0, -5.0], [20.0, -5.0], [30.0, -5.0]])[ids]
    probs = np.ones_like(logodds)
    relevance, _ = primitive_relevance(ids, probs)
    evidence, _ = primitive_relevance(ids, logodds)
    params = PipelineParams(knn_filter=False, top_k=3, min_object_gaussians=50)
    pyx = primitive_probabilities(ids, probs)
    selected = objects_from_primitives(
        means, ids, pyx, params, relevance, evidence, lengths=LENGTHS
    ).selection[0]
    assert selected.tolist()[:2] == [0, 1]


def test_object_relevance_is_the_gaussian_weighted_mean() -> None:
    relevance = np.array([[1.0], [0.0], [0.5]])
    primitive_ids = np.repeat(np.arange(3), [3, 1, 2])
    clusters = np.array([0, 0, 1])  # primitives 0 and 1 merged into cluster 0
    counts = np.bincount(primitive_ids).astype(np.float64)
    np.testing.assert_allclose(_cluster_mean_operator(clusters, counts, 2) @ relevance, [[0.75], [0.5]])


def test_an_object_below_the_threshold_for_a_task_is_not_its_answer() -> None:
    """B and C (p = 0.01 for task 1) survive pruning for task 0 but are no answers to task 1: a
    task lists only objects at or above `prune_threshold` for it (before, top-3 listed all three)."""
    means, ids, probs = _scene()
    relevance, _ = primitive_relevance(ids, probs)
    params = PipelineParams(knn_filter=False, top_k=3, min_object_gaussians=1, selection_score="relevance")
    pyx = primitive_probabilities(ids, probs)
    object_map = objects_from_primitives(means, ids, pyx, params, relevance, lengths=LENGTHS)
    assert object_map.counts["objects"] == 3  # nothing pruned: each object is relevant to some task
    assert [int(o) for o in object_map.selection[1] if o >= 0] == [0]
    assert sorted(int(o) for o in object_map.selection[0] if o >= 0) == [0, 1, 2]


def test_the_ranking_score_is_recorded_and_orders_the_ranks() -> None:
    """With 'evidence' the ranks follow the mean log-odds, not p (which is 1.0 for all three here):
    `ObjectMap.ranking` holds that score, non-increasing down each task's list."""
    means, ids, _ = _scene()
    logodds = np.array([[20.0, -5.0], [40.0, -5.0], [30.0, -5.0]])[ids]
    probs = np.ones_like(logodds)
    relevance, _ = primitive_relevance(ids, probs)
    evidence, _ = primitive_relevance(ids, logodds)
    params = PipelineParams(knn_filter=False, top_k=3, min_object_gaussians=1)
    object_map = objects_from_primitives(
        means, ids, primitive_probabilities(ids, probs), params, relevance, evidence, lengths=LENGTHS
    )
    chosen = [int(o) for o in object_map.selection[0] if o >= 0]
    assert chosen == [1, 2, 0]
    np.testing.assert_allclose(object_map.ranking[chosen, 0], [40.0, 30.0, 20.0])


def test_merge_log_records_the_pre_merge_and_the_aib_without_changing_the_map() -> None:
    # Four touching primitives: 0 and 1 identical (pre-merge), 2 close to them (an AIB merge
    # well under delta), 3 far in p(y|x) (kept apart).
    rng = np.random.default_rng(1)
    ids = np.repeat(np.arange(4), 30)
    means = rng.uniform(0, 1, size=(len(ids), 3))  # all boxes overlap
    rows = np.array([[0.3, 0.3], [0.3, 0.3], [0.3, 0.3 + 1e-4], [0.99, 0.01]])
    probs = rows[ids]
    pyx = primitive_probabilities(ids, probs)
    params = PipelineParams(knn_filter=False, top_k=2, min_object_gaussians=1)
    object_map = objects_from_primitives(means, ids, pyx, params, lengths=LENGTHS)
    log = object_map.merges
    assert log is not None
    assert log.identical.tolist() == [[0, 1]]
    assert log.node_of_primitive.tolist() == [0, 0, 1, 2]
    assert log.aib_merges.tolist() == [[0, 1]] and len(log.aib_costs) == 1
    assert 0 < log.aib_costs[0] / log.information <= params.aib_delta
    assert object_map.counts["clusters"] == 2
