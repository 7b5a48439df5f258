"""The clustering's per-view conditionals (`aib_conditionals='per_view'`, issue 23).

With dozens of agreeing views every task a Gaussian resembles at all saturates at p = 1, so two
neighbours that share a task ("move all the orange things") and differ on finer ones ("get the
orange cone" / "pick up the orange mug") get the same normalised `p(y|x)` and the AIB joins them.
The per-view rows keep what one view says, whatever the number of views.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import expit, logit

from bayesian_fields_core.objects.aib import aib
from bayesian_fields_core.objects.clustering import primitive_scores
from bayesian_fields_core.objects.edges import merge_identical
from bayesian_fields_core.objects.probabilities import per_view_probabilities
from bayesian_fields_core.params import PipelineParams

PRIOR = PipelineParams().prior
BASE = float(logit(PRIOR))


@pytest.mark.parametrize("views", [1, 2, 7, 30, 200])
def test_per_view_probability_does_not_grow_with_the_views(views: int) -> None:
    """n views of the same ratio l give what one view gives: sigmoid(logit(prior) + l)."""
    ratios = np.array([[8.0, 2.0, -3.0, 0.0]], dtype=np.float32)
    logodds = BASE + views * ratios
    got = per_view_probabilities(logodds, np.array([views]), PRIOR)
    np.testing.assert_allclose(got, expit(BASE + ratios), rtol=1e-5)


def test_an_unseen_gaussian_stays_at_the_prior() -> None:
    logodds = np.full((3, 2), BASE, dtype=np.float32)
    logodds[1] += 5.0
    got = per_view_probabilities(logodds, np.array([0, 1, 0]), PRIOR)
    np.testing.assert_allclose(got[[0, 2]], PRIOR, rtol=1e-6)
    np.testing.assert_allclose(got[1], expit(BASE + 5.0), rtol=1e-6)


def _neighbours(views: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Four primitives of 50 Gaussians, tasks (orange things, cone, mug, cyan cube): A the cone, B
    the mug beside it (both orange: the coarse task is strong in every view, the fine ones
    confusable), C a cyan cube, D the table (nothing). Edges A-B, B-C, C-D."""
    per_view = np.array(
        [
            [6.0, 2.5, 0.8, -4.0],  # A: cone
            [6.0, 0.8, 2.5, -4.0],  # B: mug
            [-4.0, -4.0, -4.0, 6.0],  # C: cyan cube
            [-4.0, -4.0, -4.0, -4.0],  # D: table
        ]
    )
    rng = np.random.default_rng(3)
    rows = np.repeat(per_view, 50, axis=0) + rng.normal(0, 0.2, size=(200, 4))
    logodds = (BASE + views * rows).astype(np.float32)
    probabilities = expit(logodds.astype(np.float64)).astype(np.float32)
    primitive_ids = np.repeat(np.arange(4), 50)
    counts = np.full(200, views, dtype=np.int32)
    return primitive_ids, probabilities, logodds, counts


def _clusters(mode: str, views: int) -> list[int]:
    """Cluster label of A, B, C, D after the pre-merge and the AIB at the defaults."""
    primitive_ids, probabilities, logodds, counts = _neighbours(views)
    params = PipelineParams(aib_conditionals=mode)  # type: ignore[arg-type]
    scores = primitive_scores(primitive_ids, probabilities, logodds, params, counts)
    edges = np.array([[0, 1], [1, 2], [2, 3]])
    merged = merge_identical(scores.pyx, edges, atol=params.identical_tolerance, eligible=scores.premerge)
    result = aib(merged.pyx, merged.edges, params.aib_delta, weights=merged.weights)
    return result.labels[merged.labels].tolist()


def test_saturated_neighbours_merge_on_fused_rows_and_stay_apart_on_per_view_rows() -> None:
    fused = _clusters("fused", views=30)
    per_view = _clusters("per_view", views=30)
    assert fused[0] == fused[1], fused  # the cone and the mug: one object (the defect)
    assert len(set(per_view)) == 4, per_view  # every primitive its own object


@pytest.mark.parametrize("views", [3, 30, 300])
def test_per_view_clustering_does_not_depend_on_the_number_of_views(views: int) -> None:
    assert _clusters("per_view", views) == _clusters("per_view", 3)


def test_the_pre_merge_joins_only_rows_at_the_prior_with_per_view_rows() -> None:
    """Saturated rows agree exactly; per_view lets the pre-merge join only unseen primitives."""
    primitive_ids, probabilities, logodds, counts = _neighbours(views=200)
    counts[primitive_ids == 3] = 0  # the table: never in an accepted mask
    logodds[primitive_ids == 3] = BASE
    scores = primitive_scores(
        primitive_ids, probabilities, logodds, PipelineParams(aib_conditionals="per_view"), counts
    )
    assert scores.premerge is not None and scores.premerge.tolist() == [False, False, False, True]
    fused = primitive_scores(
        primitive_ids, probabilities, logodds, PipelineParams(aib_conditionals="fused"), counts
    )
    assert fused.premerge is None  # the paper's rule: any rows
    # relevance and evidence (what selection ranks by) are the fused ones in both modes
    np.testing.assert_array_equal(scores.relevance, fused.relevance)
    np.testing.assert_array_equal(scores.evidence, fused.evidence)


def test_merge_identical_respects_eligibility() -> None:
    pyx = np.array([[0.5, 0.5], [0.5, 0.5], [0.5, 0.5]])
    edges = np.array([[0, 1], [1, 2]])
    assert merge_identical(pyx, edges).labels.tolist() == [0, 0, 0]
    assert merge_identical(pyx, edges, eligible=np.array([True, True, False])).labels.tolist() == [0, 0, 1]
    assert merge_identical(pyx, edges, eligible=np.zeros(3, dtype=bool)).labels.tolist() == [0, 1, 2]
