"""The primitive graph: overlap edges between axis-aligned boxes, and merging identical nodes.

Two primitives are connected when the axis-aligned boxes of their Gaussian centres overlap (paper
Sec. 4.3). Boxes are closed intervals, so touching boxes and degenerate ones (a primitive of one
Gaussian, or a planar one) still connect; `padding` grows every box by that many scene units on
each side for scenes whose primitives leave small gaps.

Edges come from a sweep-and-prune: boxes sorted by their x-minimum, every box's candidates are the
later boxes starting before its x-maximum (found with one `searchsorted`), and the y/z tests run
vectorised over all candidate pairs in bounded chunks. Cost is linear in the candidate pairs, not
quadratic in the primitives.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.objects.probabilities import membership_matrix

MAX_PAIRS_PER_CHUNK = 4_000_000
"""Bound on candidate pairs tested at once (about 100 MB of temporaries)."""

DEFAULT_IDENTICAL_ATOL = 1e-6
"""Largest per-entry difference of two `p(y|x)` rows that still counts as identical."""


def primitive_boxes(means: np.ndarray, primitive_ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned boxes (lo (P, 3), hi (P, 3)) of each primitive's Gaussian centres.

    Primitives must be numbered compactly `0..P-1` (every id present); -1 entries are ignored.
    """
    primitive_ids = np.asarray(primitive_ids)
    if means.ndim != 2 or means.shape[1] != 3 or means.shape[0] != primitive_ids.shape[0]:
        raise InputError(f"expected ({primitive_ids.shape[0]}, 3), got {means.shape}", source="edges.means")
    members = np.flatnonzero(primitive_ids >= 0)
    if members.size == 0:
        return np.zeros((0, 3)), np.zeros((0, 3))
    order = members[np.argsort(primitive_ids[members], kind="stable")]
    sorted_ids = primitive_ids[order]
    starts = np.flatnonzero(np.r_[True, sorted_ids[1:] != sorted_ids[:-1]])
    if sorted_ids[starts].tolist() != list(range(starts.size)):
        raise InputError("primitive ids must be compact 0..P-1", source="edges.primitive_ids")
    pts = means[order].astype(np.float64, copy=False)
    return np.minimum.reduceat(pts, starts, axis=0), np.maximum.reduceat(pts, starts, axis=0)


def box_overlap_edges(lo: np.ndarray, hi: np.ndarray, *, padding: float = 0.0) -> np.ndarray:
    """(E, 2) int64 pairs `i < j` of boxes whose closed, padded extents overlap on all axes."""
    lo = np.asarray(lo, dtype=np.float64) - padding
    hi = np.asarray(hi, dtype=np.float64) + padding
    n = lo.shape[0]
    if n < 2:
        return np.zeros((0, 2), dtype=np.int64)
    order = np.argsort(lo[:, 0], kind="stable")
    slo, shi = lo[order], hi[order]
    # Box a (sorted position) overlaps in x every later box b with slo[b] <= shi[a].
    end = np.searchsorted(slo[:, 0], shi[:, 0], side="right")
    counts = np.maximum(end - np.arange(n) - 1, 0)
    cumulative = np.cumsum(counts)
    found: list[np.ndarray] = []
    start = 0
    while start < n:
        # Take rows until the chunk holds about MAX_PAIRS_PER_CHUNK candidate pairs (>= one row).
        base = cumulative[start - 1] if start else 0
        stop = max(int(np.searchsorted(cumulative, base + MAX_PAIRS_PER_CHUNK, side="right")), start + 1)
        rows = np.arange(start, stop)
        row_counts = counts[start:stop]
        a = np.repeat(rows, row_counts)
        offsets = np.arange(a.size) - np.repeat(np.cumsum(row_counts) - row_counts, row_counts)
        b = a + 1 + offsets
        ok = np.all((slo[a, 1:] <= shi[b, 1:]) & (slo[b, 1:] <= shi[a, 1:]), axis=1)
        found.append(np.stack([order[a[ok]], order[b[ok]]], axis=1))
        start = stop
    pairs = np.concatenate(found) if found else np.zeros((0, 2), dtype=np.int64)
    pairs = np.sort(pairs, axis=1).astype(np.int64)
    return pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]


def overlap_edges(means: np.ndarray, primitive_ids: np.ndarray, *, padding: float = 0.0) -> np.ndarray:
    """(E, 2) int64 edges `i < j` between primitives whose centre boxes overlap."""
    lo, hi = primitive_boxes(means, primitive_ids)
    return box_overlap_edges(lo, hi, padding=padding)


@dataclass
class MergedGraph:
    """The primitive graph after identical neighbours were merged.

    labels: (P,) int64 node of each primitive. pyx: (C, Y) node conditionals. weights: (C,) number
    of primitives per node (the AIB's unnormalised `p(x)`). edges: (E', 2) int64 node pairs `i < j`.
    """

    labels: np.ndarray
    pyx: np.ndarray
    weights: np.ndarray
    edges: np.ndarray


def merge_identical(
    pyx: np.ndarray,
    edges: np.ndarray,
    *,
    atol: float = DEFAULT_IDENTICAL_ATOL,
    weights: np.ndarray | None = None,
) -> MergedGraph:
    """Merge connected primitives whose `p(y|x)` rows agree within `atol` (paper Sec. 4.3).

    Such merges cost nothing in the AIB (zero JS divergence), so doing them up front in one
    connected-components pass is exact and shrinks the graph (many primitives stay at the prior).
    Node conditionals are weighted means and node weights are sums, as the AIB would have made
    them; `weights` defaults to one per primitive.
    """
    pyx = np.asarray(pyx, dtype=np.float64)
    num = pyx.shape[0]
    edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    w = np.ones(num) if weights is None else np.asarray(weights, dtype=np.float64)
    if w.shape != (num,):
        raise InputError(f"expected ({num},), got {w.shape}", source="edges.weights")
    if edges.size and (edges.min() < 0 or edges.max() >= num):
        raise InputError(f"edge endpoint outside [0, {num})", source="edges.edges")
    same = np.all(np.abs(pyx[edges[:, 0]] - pyx[edges[:, 1]]) <= atol, axis=1)
    tied = edges[same]
    graph = coo_matrix((np.ones(tied.shape[0]), (tied[:, 0], tied[:, 1])), shape=(num, num))
    count, labels = connected_components(graph, directed=False)
    labels = labels.astype(np.int64)
    members = membership_matrix(labels, count)
    node_w = members @ w
    node_pyx = (members @ (pyx * w[:, None])) / node_w[:, None]
    node_edges = np.sort(labels[edges], axis=1)
    node_edges = np.unique(node_edges[node_edges[:, 0] != node_edges[:, 1]], axis=0)
    return MergedGraph(labels=labels, pyx=node_pyx, weights=node_w, edges=node_edges.reshape(-1, 2))
