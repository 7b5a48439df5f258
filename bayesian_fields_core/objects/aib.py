"""Agglomerative Information Bottleneck on the primitive graph (Slonim & Tishby 1999, as in Clio).

Nodes start as primitives with mass `p(x)` (uniform, or the given weights normalised) and
conditionals `p(y|x)` over tasks + null. Merging nodes i and j loses
`d_ij = (p_i + p_j) * JS_pi[p(y|i), p(y|j)]` with weights `pi = (p_i, p_j) / (p_i + p_j)`, where
`JS_pi[a, b] = H(pi_a a + pi_b b) - pi_a H(a) - pi_b H(b)`. The cheapest edge is merged greedily:
the new node has `p = p_i + p_j`, the `p`-weighted mean conditional and the union of both
neighbourhoods (only graph neighbours may merge).

Stopping rule (METHOD.md step 9): stop before the next merge when its relative information loss
`(I(C;Y)_before - I(C;Y)_after) / I(X;Y)` exceeds `delta`. With
`I(C;Y) = sum_c p_c sum_y p(y|c) log(p(y|c) / q(y))` for a *fixed* reference `q`, the term in
`log q` only depends on `sum_c p_c p(y|c)`, which merging preserves, so the loss of a merge is
exactly `d_ij` whatever `q` is. `q` therefore only sets the normaliser `I(X;Y)`: Clio uses a
uniform `q` (`py_mode="uniform"`, default), giving `I(X;Y) = log|Y| - sum_x p_x H(p(y|x))`;
`py_mode="marginal"` uses the true marginal and the textbook mutual information.

Two exact drivers, chosen by graph size (`dense_limit`), make the same merges (same costs, ties
broken by the lower node pair):
- dense (up to `dense_limit` nodes): an (n, n) cost matrix with per-row minima; a merge rewrites
  one row/column and re-scans only the rows whose minimum pointed at the merged pair, all in
  numpy, so a merge costs O(n) vectorised work however many neighbours the merged node has
  (large "background" clusters touch almost everything, which makes per-edge Python work slow).
- heap (larger graphs, O(E) memory): every node caches its cheapest edge and a binary heap with
  lazy invalidation (per-node version counters) holds those; a merge re-weights the merged
  node's edges in one vectorised step and rescans only the neighbours whose cached best edge
  touched the merged pair, `O(E log E)` overall.
- Both drivers compute a pair's cost with the lower node id first, so equal costs compare
  bit-for-bit and ties break identically (by the lower node pair).
"""

from __future__ import annotations

import heapq
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.special import entr

from bayesian_fields_core.errors import InputError

DEFAULT_DELTA = 1e-5
"""Clio's default threshold on the relative information loss of a merge."""

PyMode = Literal["uniform", "marginal"]
_TINY = 1e-12

DEFAULT_DENSE_LIMIT = 3072
"""Largest node count for the dense driver: its (n, n) float64 costs take 8 n^2 bytes (72 MiB)."""


def entropy(dist: np.ndarray) -> np.ndarray:
    """Shannon entropy (nats) of each row of a (..., Y) array of distributions; 0 log 0 = 0."""
    return entr(dist).sum(axis=-1)


def merge_cost(p_i: np.ndarray, c_i: np.ndarray, p_j: np.ndarray, c_j: np.ndarray) -> np.ndarray:
    """`d_ij = (p_i + p_j) JS_pi[c_i, c_j]` for masses (...,) and conditionals (..., Y).

    Computed as `(p_i + p_j) H(mix) - p_i H(c_i) - p_j H(c_j)`, clipped at 0 against rounding.
    """
    p_i = np.asarray(p_i, dtype=np.float64)
    p_j = np.asarray(p_j, dtype=np.float64)
    total = p_i + p_j
    mix = (p_i[..., None] * c_i + p_j[..., None] * c_j) / total[..., None]
    cost = total * entropy(mix) - p_i * entropy(c_i) - p_j * entropy(c_j)
    return np.maximum(cost, 0.0)


def mutual_information(px: np.ndarray, pyx: np.ndarray, py_mode: PyMode = "uniform") -> float:
    """`I(X;Y)` in nats for masses `px` (P,) and conditionals `pyx` (P, Y) (see module doc)."""
    cond_entropy = float(px @ entropy(pyx))
    if py_mode == "uniform":
        return float(np.log(pyx.shape[1])) - cond_entropy
    if py_mode == "marginal":
        return float(entropy(px @ pyx)) - cond_entropy
    raise InputError(f"unknown py_mode {py_mode!r}", source="aib.py_mode")


@dataclass
class AIBResult:
    """Outcome of `aib`.

    labels: (P,) int64 cluster of each input node, compact `0..C-1`.
    pyx: (C, Y) cluster conditionals. mass: (C,) cluster `p(c)` (sums to 1).
    merges: (K, 2) int64 node pairs in merge order (the lower id survives and names the union).
    costs: (K,) information loss `d_ij` of each merge. information: `I(X;Y)` of the input.
    stopped_at: relative loss of the first merge refused (inf when the graph ran out of edges).
    """

    labels: np.ndarray
    pyx: np.ndarray
    mass: np.ndarray
    merges: np.ndarray
    costs: np.ndarray
    information: float
    stopped_at: float


def _check(pyx: np.ndarray, edges: np.ndarray, weights: np.ndarray | None) -> np.ndarray:
    if pyx.ndim != 2 or pyx.shape[1] < 1:
        raise InputError(f"expected (P, Y), got {pyx.shape}", source="aib.pyx")
    if not np.all(np.isfinite(pyx)) or np.any(pyx < 0) or not np.allclose(pyx.sum(axis=1), 1.0, atol=1e-6):
        raise InputError("rows must be probability distributions", source="aib.pyx")
    if edges.size and (edges.min() < 0 or edges.max() >= pyx.shape[0]):
        raise InputError(f"edge endpoint outside [0, {pyx.shape[0]})", source="aib.edges")
    w = np.ones(pyx.shape[0]) if weights is None else np.asarray(weights, dtype=np.float64)
    if w.shape != (pyx.shape[0],) or np.any(w <= 0):
        raise InputError(f"expected ({pyx.shape[0]},) positive weights", source="aib.weights")
    return w / w.sum() if w.size else w


class _Nodes:
    """Cluster state shared by both drivers: masses, conditionals and their cached entropies."""

    def __init__(self, px: np.ndarray, pyx: np.ndarray) -> None:
        self.mass = px.copy()
        self.cond = pyx.copy()
        self.ent = entropy(pyx)

    def pair_costs(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Merge costs of the node pairs (a[e], b[e])."""
        m_a, m_b = self.mass[a], self.mass[b]
        total = m_a + m_b
        mix = (m_a[:, None] * self.cond[a] + m_b[:, None] * self.cond[b]) / total[:, None]
        return np.maximum(total * entropy(mix) - m_a * self.ent[a] - m_b * self.ent[b], 0.0)

    def merge(self, i: int, j: int) -> None:
        """Fold node j into node i."""
        total = self.mass[i] + self.mass[j]
        self.cond[i] = (self.mass[i] * self.cond[i] + self.mass[j] * self.cond[j]) / total
        self.mass[i] = total
        self.mass[j] = 0.0
        self.ent[i] = entropy(self.cond[i])


_Stop = Callable[[float], bool]


def _merge_heap(nodes: _Nodes, edges: np.ndarray, stop: _Stop) -> tuple[list[tuple[int, int]], list[float]]:
    """Greedy merging with per-node best edges in a heap (see module doc).

    Each node caches its cheapest edge, keyed `(cost, lo, hi)`; a heap holds one entry per node
    (stale once the node's version moved). After a merge only the merged node's edges change:
    its neighbours compare the new edge with their cached best in one vectorised step, and only
    those whose best was an edge to the merged pair rescan their own edges. Compared with a heap
    of every edge this pushes a handful of entries per merge instead of one per neighbour, which
    matters around large background clusters with thousands of neighbours.
    """
    num = nodes.mass.size
    version = np.zeros(num, dtype=np.int64)
    best_cost = np.full(num, np.inf)
    best_arg = np.full(num, -1, dtype=np.int64)
    neighbours: list[set[int]] = [set() for _ in range(num)]
    for a, b in edges.tolist():
        neighbours[a].add(b)
        neighbours[b].add(a)

    # Initial best edge of every node, from all edge costs at once.
    cost0 = nodes.pair_costs(edges[:, 0], edges[:, 1])
    src = np.concatenate([edges[:, 0], edges[:, 1]])
    dst = np.concatenate([edges[:, 1], edges[:, 0]])
    c2 = np.concatenate([cost0, cost0])
    lo2 = np.concatenate([edges[:, 0], edges[:, 0]])
    hi2 = np.concatenate([edges[:, 1], edges[:, 1]])
    order = np.lexsort((hi2, lo2, c2, src))
    first = order[np.r_[True, src[order][1:] != src[order][:-1]]]
    best_cost[src[first]] = c2[first]
    best_arg[src[first]] = dst[first]
    heap = [
        (float(best_cost[k]), min(k, int(best_arg[k])), max(k, int(best_arg[k])), k, 0)
        for k in src[first].tolist()
    ]
    heapq.heapify(heap)

    def edges_of(k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
        """(neighbours, lo, hi, costs) of node k's edges after recording its best; None if it has none."""
        version[k] += 1
        if not neighbours[k]:
            best_cost[k], best_arg[k] = np.inf, -1
            return None
        ms = np.fromiter(neighbours[k], dtype=np.int64, count=len(neighbours[k]))
        lo, hi = np.minimum(ms, k), np.maximum(ms, k)
        c = nodes.pair_costs(lo, hi)
        top = int(np.lexsort((hi, lo, c))[0])
        best_cost[k], best_arg[k] = c[top], ms[top]
        heapq.heappush(heap, (float(c[top]), int(lo[top]), int(hi[top]), k, int(version[k])))
        return ms, lo, hi, c

    merges: list[tuple[int, int]] = []
    costs: list[float] = []
    while heap:
        cost, i, j, k, v = heapq.heappop(heap)
        if version[k] != v:
            continue
        if stop(cost):
            break
        merges.append((i, j))
        costs.append(cost)
        nodes.merge(i, j)
        version[j] += 1
        best_cost[j], best_arg[j] = np.inf, -1
        for m in neighbours[j]:
            if m != i:
                neighbours[m].discard(j)
                neighbours[m].add(i)
        neighbours[i] |= neighbours[j]
        neighbours[i] -= {i, j}
        neighbours[j] = set()
        found = edges_of(i)  # every edge of i changed: i's own best comes from these
        if found is None:
            continue
        ks, lo, hi, c = found
        pointed = (best_arg[ks] == i) | (best_arg[ks] == j)
        cur_lo = np.minimum(ks, best_arg[ks])
        cur_hi = np.maximum(ks, best_arg[ks])
        cur = best_cost[ks]
        # A neighbour whose cached best was an edge to i or j: when the new edge to i is strictly
        # cheaper than that best, it beats every other edge of the neighbour too (none of those
        # changed); otherwise the neighbour rescans.
        better = (pointed & (c < cur)) | (
            ~pointed & ((c < cur) | ((c == cur) & ((lo < cur_lo) | ((lo == cur_lo) & (hi < cur_hi)))))
        )
        stale = pointed & ~better
        for n in np.flatnonzero(better).tolist():
            k = int(ks[n])
            version[k] += 1
            best_cost[k], best_arg[k] = c[n], i
            heapq.heappush(heap, (float(c[n]), int(lo[n]), int(hi[n]), k, int(version[k])))
        for k in ks[stale].tolist():
            edges_of(k)
    return merges, costs


def _merge_dense(nodes: _Nodes, edges: np.ndarray, stop: _Stop) -> tuple[list[tuple[int, int]], list[float]]:
    """Greedy merging on a dense cost matrix with cached row minima (see module doc)."""
    num = nodes.mass.size
    cost = np.full((num, num), np.inf)
    adjacent = np.zeros((num, num), dtype=bool)
    a, b = edges[:, 0], edges[:, 1]
    cost[a, b] = cost[b, a] = nodes.pair_costs(a, b)
    adjacent[a, b] = adjacent[b, a] = True
    row_arg = cost.argmin(axis=1)
    row_min = cost[np.arange(num), row_arg]
    merges: list[tuple[int, int]] = []
    costs: list[float] = []
    while num:
        r = int(row_min.argmin())
        best = float(row_min[r])
        if best == np.inf or stop(best):
            break
        # The lowest row holding the minimum and its lowest column: the lexicographically
        # smallest pair (i < j) among the cheapest edges, as the heap driver pops it.
        i, j = r, int(row_arg[r])
        merges.append((i, j))
        costs.append(best)
        nodes.merge(i, j)
        adjacent[i] |= adjacent[j]
        adjacent[j] = False
        adjacent[:, j] = False
        adjacent[i, [i, j]] = False
        adjacent[:, i] = adjacent[i]
        ks = np.flatnonzero(adjacent[i])
        cost[j] = np.inf
        cost[:, j] = np.inf
        cost[i] = np.inf
        cost[i, ks] = nodes.pair_costs(np.minimum(ks, i), np.maximum(ks, i))
        cost[:, i] = cost[i]
        row_min[j] = np.inf
        stale = np.flatnonzero((row_arg == i) | (row_arg == j))
        stale = stale[stale != j]
        if stale.size:
            row_arg[stale] = cost[stale].argmin(axis=1)
            row_min[stale] = cost[stale, row_arg[stale]]
        # Neighbours whose new edge to i beats (or ties with a lower id) their cached minimum.
        new = cost[ks, i]
        better = (new < row_min[ks]) | ((new == row_min[ks]) & (i < row_arg[ks]))
        row_min[ks[better]] = new[better]
        row_arg[ks[better]] = i
        row_arg[i] = int(cost[i].argmin())
        row_min[i] = cost[i, row_arg[i]]
    return merges, costs


def aib(
    pyx: np.ndarray,
    edges: np.ndarray,
    delta: float = DEFAULT_DELTA,
    *,
    weights: np.ndarray | None = None,
    py_mode: PyMode = "uniform",
    dense_limit: int = DEFAULT_DENSE_LIMIT,
) -> AIBResult:
    """Cluster graph nodes with conditionals `pyx` (P, Y) along `edges` (E, 2) until the next
    merge would lose more than `delta` of `I(X;Y)`; `weights` (P,) default to uniform `p(x)`.

    `dense_limit` picks the driver (dense matrix up to that many nodes, heap above); both make
    the same merges.
    """
    pyx = np.asarray(pyx, dtype=np.float64)
    edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    num = pyx.shape[0]
    px = _check(pyx, edges, weights)
    info = mutual_information(px, pyx, py_mode) if num else 0.0
    stopped_at = [float("inf")]

    def stop(cost: float) -> bool:
        if info > _TINY:
            rel = cost / info
        else:
            rel = 0.0 if cost <= _TINY else float("inf")
        if rel > delta:
            stopped_at[0] = rel
            return True
        return False

    edges = np.unique(np.sort(edges[edges[:, 0] != edges[:, 1]], axis=1), axis=0).reshape(-1, 2)
    nodes = _Nodes(px, pyx)
    driver = _merge_dense if num <= dense_limit else _merge_heap
    merges, costs = driver(nodes, edges, stop) if edges.size else ([], [])

    merge_arr = np.asarray(merges, dtype=np.int64).reshape(-1, 2)
    graph = coo_matrix((np.ones(len(merges)), (merge_arr[:, 0], merge_arr[:, 1])), shape=(num, num))
    count, labels = connected_components(graph, directed=False)
    labels = labels.astype(np.int64)
    cluster_mass = np.bincount(labels, weights=px, minlength=count)
    cluster_pyx = np.zeros((count, pyx.shape[1]))
    np.add.at(cluster_pyx, labels, pyx * px[:, None])
    cluster_pyx /= cluster_mass[:, None]
    return AIBResult(
        labels=labels,
        pyx=cluster_pyx,
        mass=cluster_mass,
        merges=merge_arr,
        costs=np.asarray(costs, dtype=np.float64),
        information=info,
        stopped_at=stopped_at[0],
    )
