"""Overlap edges, identical-node merging, the JS edge weight and the AIB merge sequence."""

import math

import numpy as np
import pytest

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.objects.aib import aib, merge_cost, mutual_information
from bayesian_fields_core.objects.edges import (
    box_overlap_edges,
    merge_identical,
    overlap_edges,
    primitive_boxes,
)


def _four_primitives() -> tuple[np.ndarray, np.ndarray]:
    means = np.array(
        [
            [0, 0, 0], [1, 1, 1],  # A: box [0,1]^3
            [0.5, 0.5, 0.5], [2, 2, 2],  # B: [0.5,2]^3, overlaps A
            [3, 0, 0], [4, 1, 1],  # C: x in [3,4], apart from all
            [1, 1, 1],  # D: one Gaussian on A's corner (touches A, inside B)
        ],
        dtype=np.float32,
    )  # fmt: skip
    return means, np.array([0, 0, 1, 1, 2, 2, 3])


def test_boxes_and_edges() -> None:
    means, ids = _four_primitives()
    lo, hi = primitive_boxes(means, ids)
    np.testing.assert_allclose(lo[1], [0.5, 0.5, 0.5])
    np.testing.assert_allclose(hi[2], [4, 1, 1])
    assert overlap_edges(means, ids).tolist() == [[0, 1], [0, 3], [1, 3]]
    # Padding 0.5 makes B (x <= 2.5) touch C (x >= 2.5).
    assert overlap_edges(means, ids, padding=0.5).tolist() == [[0, 1], [0, 3], [1, 2], [1, 3]]


def test_non_compact_ids_raise() -> None:
    means, ids = _four_primitives()
    with pytest.raises(InputError, match="compact"):
        primitive_boxes(means, np.where(ids == 3, 5, ids))


@pytest.mark.parametrize("long_axis", [0, 1, 2])
def test_sweep_matches_brute_force(long_axis: int) -> None:
    rng = np.random.default_rng(1)
    lo = rng.uniform(0, 10, size=(300, 3))
    extent = rng.exponential(0.8, size=(300, 3))
    extent[:, long_axis] *= 6  # boxes long on one axis: the sweep must pick another one
    hi = lo + extent
    got = box_overlap_edges(lo, hi)
    overlap = np.all((lo[:, None] <= hi[None]) & (lo[None] <= hi[:, None]), axis=2)
    i, j = np.nonzero(np.triu(overlap, k=1))
    assert got.tolist() == np.stack([i, j], axis=1).tolist()
    assert len(got) > 100


def test_merge_identical() -> None:
    pyx = np.array([[0.2, 0.8], [0.2, 0.8], [0.2, 0.8], [0.6, 0.4]])
    # 0-1 identical and connected -> one node; 2 is identical too but only connected to 3.
    graph = merge_identical(pyx, np.array([[0, 1], [1, 3], [2, 3]]))
    assert graph.labels.tolist() == [0, 0, 1, 2]
    assert graph.weights.tolist() == [2.0, 1.0, 1.0]
    assert graph.edges.tolist() == [[0, 2], [1, 2]]
    np.testing.assert_allclose(graph.pyx, pyx[[0, 2, 3]])
    assert graph.identical.tolist() == [[0, 1]]  # the record of what the pre-merge tied


def test_js_edge_weight_hand_values() -> None:
    # Equal masses 1/2 each, disjoint supports: JS = H(1/2, 1/2) = ln 2; d = (1/2 + 1/2) ln 2.
    d = merge_cost(np.array(0.5), np.array([1.0, 0.0]), np.array(0.5), np.array([0.0, 1.0]))
    assert float(d) == pytest.approx(math.log(2))
    # Masses 1/4 and 3/4, a = (1, 0), b = (1/2, 1/2): mix = (5/8, 3/8),
    # JS = H(5/8, 3/8) - 3/4 ln 2 = 0.661563 - 0.519860 = 0.141703, d = 1 * JS.
    d = merge_cost(np.array(0.25), np.array([1.0, 0.0]), np.array(0.75), np.array([0.5, 0.5]))
    assert float(d) == pytest.approx(0.141703, abs=1e-6)
    # Identical conditionals cost nothing.
    assert float(
        merge_cost(np.array(0.1), np.array([0.3, 0.7]), np.array(0.2), np.array([0.3, 0.7]))
    ) == pytest.approx(0.0, abs=1e-15)


def _chain() -> tuple[np.ndarray, np.ndarray]:
    pyx = np.array([[0.9, 0.1], [0.9, 0.1], [0.8, 0.2], [0.1, 0.9], [0.2, 0.8]])
    return pyx, np.array([[0, 1], [1, 2], [2, 3], [3, 4]])


def test_aib_merge_order_and_stop() -> None:
    pyx, edges = _chain()
    # Uniform p(x) = 0.2; Clio's I(X;Y) = ln 2 - mean H(row) = 0.297936.
    # Costs: (0,1): 0. (3,4): 0.4 [H(.15) - (H(.1) + H(.2)) / 2] = 0.0039866 -> relative 0.01338.
    # ({0,1},2): 0.6 [H(.8667) - 2/3 H(.1) - 1/3 H(.2)] = 0.0054910 -> relative 0.01843.
    result = aib(pyx, edges, delta=0.015)
    assert result.information == pytest.approx(0.297936, abs=1e-6)
    assert result.merges.tolist() == [[0, 1], [3, 4]]
    np.testing.assert_allclose(result.costs, [0.0, 0.0039866], atol=1e-7)
    assert result.stopped_at == pytest.approx(0.018430, abs=1e-5)
    assert result.labels.tolist() == [0, 0, 1, 2, 2]
    np.testing.assert_allclose(result.pyx[2], [0.15, 0.85])
    np.testing.assert_allclose(result.mass, [0.4, 0.2, 0.4])

    everything = aib(pyx, edges, delta=10.0)
    assert everything.merges.tolist() == [[0, 1], [3, 4], [0, 2], [0, 3]]
    assert everything.labels.tolist() == [0] * 5
    assert everything.stopped_at == math.inf  # ran out of edges


def test_aib_loss_is_exactly_information_drop() -> None:
    rng = np.random.default_rng(3)
    pyx = rng.dirichlet(np.ones(4), size=30)
    edges = np.array([[i, j] for i in range(30) for j in range(i + 1, min(i + 4, 30))])
    result = aib(pyx, edges, delta=0.2)
    for mode in ("uniform", "marginal"):
        before = mutual_information(np.full(30, 1 / 30), pyx, mode)
        after = mutual_information(result.mass, result.pyx, mode)
        assert before - after == pytest.approx(result.costs.sum(), rel=1e-9, abs=1e-12)
    assert result.costs.sum() / result.information <= 0.2 * len(result.costs)


def test_aib_only_merges_neighbours() -> None:
    pyx = np.array([[0.5, 0.5], [0.5, 0.5], [0.9, 0.1]])
    result = aib(pyx, np.array([[0, 2], [1, 2]]), delta=0.0)
    # 0 and 1 are identical but not adjacent; merging through 2 would cost information.
    assert result.labels.tolist() == [0, 1, 2]


def test_aib_rejects_non_distributions() -> None:
    with pytest.raises(InputError, match="aib.pyx"):
        aib(np.array([[0.5, 0.6]]), np.zeros((0, 2)))


def _reference_aib(pyx: np.ndarray, edges: np.ndarray, delta: float) -> tuple[list[int], list[float]]:
    """Textbook greedy AIB, quadratic and obviously right: rescore every live edge each step."""
    mass = np.full(len(pyx), 1 / len(pyx))
    cond = pyx.copy()
    label = list(range(len(pyx)))
    info = mutual_information(mass, pyx)
    live = {(int(a), int(b)) for a, b in edges}
    costs: list[float] = []
    while live:
        pairs = sorted(live)
        cost = [float(merge_cost(mass[a], cond[a], mass[b], cond[b])) for a, b in pairs]
        best = int(np.argmin(cost))
        if cost[best] / info > delta:
            break
        i, j = pairs[best]
        costs.append(cost[best])
        cond[i] = (mass[i] * cond[i] + mass[j] * cond[j]) / (mass[i] + mass[j])
        mass[i] += mass[j]
        label = [i if x == j else x for x in label]
        live = {tuple(sorted((i if a == j else a, i if b == j else b))) for a, b in live}
        live = {(a, b) for a, b in live if a != b}
    return label, costs


def test_aib_matches_reference_greedy_merging() -> None:
    rng = np.random.default_rng(5)
    # Repeated rows create zero-cost merges and exact cost ties.
    pyx = rng.dirichlet(np.ones(5), size=40)[rng.integers(0, 25, size=60)]
    edges = np.unique(np.sort(rng.integers(0, 60, size=(240, 2)), axis=1), axis=0)
    edges = edges[edges[:, 0] != edges[:, 1]]
    result = aib(pyx, edges, delta=0.05)
    label, costs = _reference_aib(pyx, edges, delta=0.05)
    assert len(result.merges) > 20
    assert len(result.merges) == len(costs)
    np.testing.assert_allclose(np.sort(result.costs), np.sort(costs), atol=1e-12)
    # Same partition (ids may differ): the co-membership matrices agree.
    np.testing.assert_array_equal(
        result.labels[:, None] == result.labels[None, :], np.equal.outer(label, label)
    )


def test_aib_degenerate_graphs() -> None:
    assert aib(np.zeros((0, 3)), np.zeros((0, 2))).labels.shape == (0,)
    uniform = np.full((3, 3), 1 / 3)
    assert aib(uniform, np.zeros((0, 2))).labels.tolist() == [0, 1, 2]  # no edges, no merges
    # I(X;Y) = 0 (every row uniform): free merges still happen along edges.
    assert aib(uniform, np.array([[0, 1], [1, 2]])).labels.tolist() == [0, 0, 0]
