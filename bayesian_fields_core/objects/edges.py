"""The primitive graph: overlap edges between axis-aligned boxes, and merging identical nodes.

Two primitives are connected when the axis-aligned boxes of their Gaussian centres overlap (paper
Sec. 4.3). Boxes are closed intervals, so touching boxes and degenerate ones (a primitive of one
Gaussian, or a planar one) still connect; `padding` grows every box by that many scene units on
each side for scenes whose primitives leave small gaps.

Edges come from a sweep-and-prune: boxes sorted by their minimum along the axis where that leaves
the fewest candidates, every box's candidates are the later boxes starting before its maximum, and
a compiled loop tests the other two axes. Cost is linear in the candidate pairs, not quadratic in
the primitives (8 M candidates, 774 k edges: about 0.05 s; the vectorised numpy version took 1 s).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from bayesian_fields_core.compute.jit import compiled
from bayesian_fields_core.errors import InputError
from bayesian_fields_core.objects.probabilities import membership_matrix
from bayesian_fields_core.params import default


def primitive_boxes(means: np.ndarray, primitive_ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned boxes (lo (P, 3), hi (P, 3)) of each primitive's Gaussian centres.

    Primitives must be numbered compactly `0..P-1` (every id present); -1 entries are ignored.
    """
    primitive_ids = np.asarray(primitive_ids)
    if means.ndim != 2 or means.shape[1] != 3 or means.shape[0] != primitive_ids.shape[0]:
        raise InputError(f"expected ({primitive_ids.shape[0]}, 3), got {means.shape}", source="edges.means")
    num = int(primitive_ids.max(initial=-1)) + 1
    lo, hi, counts = _group_bounds(
        np.ascontiguousarray(primitive_ids, dtype=np.int64), np.ascontiguousarray(means), num
    )
    if num and counts.min() == 0:
        raise InputError("primitive ids must be compact 0..P-1", source="edges.primitive_ids")
    return lo, hi


@compiled
def _group_bounds(ids: np.ndarray, points: np.ndarray, num: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-id minimum and maximum (num, 3) float64 of `points` (N, 3) and the (num,) member
    counts, in one pass (ids < 0 skipped): the sort-and-reduceat it replaces took 50 ms at the
    scale bench; min and max are exact, so the boxes are the same floats."""
    lo = np.full((num, 3), np.inf)
    hi = np.full((num, 3), -np.inf)
    counts = np.zeros(num, dtype=np.int64)
    for n in range(ids.shape[0]):
        g = ids[n]
        if g < 0:
            continue
        counts[g] += 1
        for d in range(3):
            v = np.float64(points[n, d])
            lo[g, d] = min(lo[g, d], v)
            hi[g, d] = max(hi[g, d], v)
    return lo, hi, counts


@compiled
def _sweep(other: np.ndarray, order: np.ndarray, end: np.ndarray) -> np.ndarray:
    """Pairs of boxes overlapping on all axes, as (min id, max id). Boxes are in sweep order:
    `order[a]` is the id of the a-th box, `end[a]` the first position whose minimum along the
    sweep axis lies beyond box a's maximum, and `other` (n, 4) holds `[lo, hi, lo, hi]` of the
    two other axes in that order, so the candidates of a box are read sequentially (gathering
    them through `order` from (n, 3) arrays took 2.5x as long at the scale bench)."""
    n = order.shape[0]
    out = np.empty((max(n, 16), 2), dtype=np.int64)
    count = 0
    for a in range(n):
        lo_a, hi_a, lo_b, hi_b = other[a, 0], other[a, 1], other[a, 2], other[a, 3]
        p = order[a]
        for b in range(a + 1, end[a]):
            if other[b, 0] > hi_a or lo_a > other[b, 1] or other[b, 2] > hi_b or lo_b > other[b, 3]:
                continue
            q = order[b]
            if count == out.shape[0]:
                grown = np.empty((2 * count, 2), dtype=np.int64)
                grown[:count] = out
                out = grown
            out[count, 0], out[count, 1] = min(p, q), max(p, q)
            count += 1
    return out[:count]


def box_overlap_edges(lo: np.ndarray, hi: np.ndarray, *, padding: float | None = None) -> np.ndarray:
    """(E, 2) int64 pairs `i < j` of boxes whose closed, padded extents overlap on all axes,
    sorted. `padding`: scene units each box grows by on every side (None: none); the cluster
    stage passes `SceneLengths.edge_padding`, a fraction of the scene scale."""
    padding = 0.0 if padding is None else float(padding)
    lo = np.ascontiguousarray(np.asarray(lo, dtype=np.float64) - padding)
    hi = np.ascontiguousarray(np.asarray(hi, dtype=np.float64) + padding)
    n = lo.shape[0]
    if n < 2:
        return np.zeros((0, 2), dtype=np.int64)
    best = None
    for axis in range(3):  # sweep along the axis with the fewest candidate pairs
        order = np.argsort(lo[:, axis], kind="stable")
        end = np.searchsorted(lo[order, axis], hi[order, axis], side="right")
        candidates = int(np.maximum(end - np.arange(n) - 1, 0).sum())
        if best is None or candidates < best[0]:
            best = (candidates, axis, order, end)
    assert best is not None  # n >= 2: every axis was swept
    _, axis, order, end = best
    a, b = (d for d in range(3) if d != axis)
    other = np.stack([lo[order, a], hi[order, a], lo[order, b], hi[order, b]], axis=1)
    pairs = _sweep(np.ascontiguousarray(other), order.astype(np.int64), end.astype(np.int64))
    keys = np.sort(pairs[:, 0] * n + pairs[:, 1])  # each pair is found once: no duplicates
    return np.stack([keys // n, keys % n], axis=1)


def overlap_edges(
    means: np.ndarray, primitive_ids: np.ndarray, *, padding: float | None = None
) -> np.ndarray:
    """(E, 2) int64 edges `i < j` between primitives whose centre boxes overlap."""
    lo, hi = primitive_boxes(means, primitive_ids)
    return box_overlap_edges(lo, hi, padding=padding)


@dataclass
class MergedGraph:
    """The primitive graph after identical neighbours were merged.

    labels: (P,) int64 node of each primitive. pyx: (C, Y) node conditionals. weights: (C,) number
    of primitives per node (the AIB's unnormalised `p(x)`). edges: (E', 2) int64 node pairs `i < j`.
    identical: (K, 2) int64 the primitive edges whose rows agreed within the tolerance (the
    pre-merge's own record: they join the `P - C` unions, more than that when they close cycles),
    kept so a study of *which* neighbours the pre-merge joins needs no copy of the test.
    """

    labels: np.ndarray
    pyx: np.ndarray
    weights: np.ndarray
    edges: np.ndarray
    identical: np.ndarray


def merge_identical(
    pyx: np.ndarray,
    edges: np.ndarray,
    *,
    atol: float = default("identical_tolerance"),
    weights: np.ndarray | None = None,
    eligible: np.ndarray | None = None,
) -> MergedGraph:
    """Merge connected primitives whose `p(y|x)` rows agree within `atol` (paper Sec. 4.3).

    Such merges cost nothing in the AIB (zero JS divergence), so doing them up front in one
    connected-components pass is exact and shrinks the graph (many primitives stay at the prior).
    Node conditionals are weighted means and node weights are sums, as the AIB would have made
    them; `weights` defaults to one per primitive. `eligible` (P,) bool limits the pre-merge to
    edges between eligible primitives (the paper meant it for primitives still at their prior;
    saturated rows agree too, and joining those up front hides their differences from the AIB).
    """
    pyx = np.asarray(pyx, dtype=np.float64)
    num = pyx.shape[0]
    edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    w = np.ones(num) if weights is None else np.asarray(weights, dtype=np.float64)
    if w.shape != (num,):
        raise InputError(f"expected ({num},), got {w.shape}", source="edges.weights")
    if edges.size and (edges.min() < 0 or edges.max() >= num):
        raise InputError(f"edge endpoint outside [0, {num})", source="edges.edges")
    same = _identical_rows(pyx, edges, atol)
    if eligible is not None:
        ok = np.asarray(eligible, dtype=bool)
        if ok.shape != (num,):
            raise InputError(f"expected ({num},), got {ok.shape}", source="edges.eligible")
        same &= ok[edges[:, 0]] & ok[edges[:, 1]]
    tied = edges[same]
    graph = coo_matrix((np.ones(tied.shape[0]), (tied[:, 0], tied[:, 1])), shape=(num, num))
    count, labels = connected_components(graph, directed=False)
    labels = labels.astype(np.int64)
    members = membership_matrix(labels, count)
    node_w = members @ w
    node_pyx = (members @ (pyx * w[:, None])) / node_w[:, None]
    return MergedGraph(
        labels=labels,
        pyx=node_pyx,
        weights=node_w,
        edges=unique_pairs(labels[edges], count),
        identical=tied,
    )


def sorted_unique(values: np.ndarray) -> np.ndarray:
    """Distinct values of a 1-D array, ascending: `np.unique` by one sort and a neighbour test.

    numpy >= 2.3 answers `np.unique` of wide-range int64 with a hash table that is ~50x slower
    than sorting here (1 s against 20 ms for 774 k keys), so hot paths use this instead.
    """
    ordered = np.sort(np.asarray(values).reshape(-1))
    if ordered.size < 2:
        return ordered
    return ordered[np.concatenate([[True], ordered[1:] != ordered[:-1]])]


def unique_pairs(pairs: np.ndarray, num: int) -> np.ndarray:
    """(E', 2) int64 distinct undirected pairs `i < j` of nodes `0..num-1`, self-pairs dropped,
    sorted. One int64 key per pair: a 1-D unique is several times faster than `unique(axis=0)`."""
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    lo, hi = np.minimum(pairs[:, 0], pairs[:, 1]), np.maximum(pairs[:, 0], pairs[:, 1])
    distinct = lo != hi
    keys = sorted_unique(lo[distinct] * max(num, 1) + hi[distinct])
    return np.stack([keys // max(num, 1), keys % max(num, 1)], axis=1)


@compiled
def _identical_rows(pyx: np.ndarray, edges: np.ndarray, atol: float) -> np.ndarray:
    """(E,) whether the two rows of each edge agree within `atol` in every entry (stops at the
    first differing entry instead of materialising two (E, Y) gathers)."""
    same = np.ones(edges.shape[0], dtype=np.bool_)
    for e in range(edges.shape[0]):
        a, b = edges[e, 0], edges[e, 1]
        for y in range(pyx.shape[1]):
            if abs(pyx[a, y] - pyx[b, y]) > atol:
                same[e] = False
                break
    return same
