"""The AIB's greedy merge loop, compiled with numba.

Why compiled: agglomeration is inherently sequential (each merge changes the costs the next one
is chosen from), so numpy can only vectorise inside one merge. At the paper's scale (thousands of
nodes, hundreds of thousands of edges, "background" clusters with thousands of neighbours) the
per-merge Python and numpy-call overhead dominated: 5-6 s for 8,500 nodes. The same algorithm as a
compiled loop takes a fraction of a second (`bench/bench_scale.py`).

Algorithm (`O(E log E)`): one binary heap holds an entry `(cost, lo, hi, version_lo, version_hi)`
per edge; an entry is current while both endpoints keep the versions it was pushed with. Merging
the cheapest current edge folds `hi` into `lo` (the lower id survives and names the union), bumps
`lo`'s version (invalidating all its old entries), gives `lo` the union of both neighbourhoods and
pushes one fresh entry per neighbour. Neighbour lists of other nodes are not rewritten: they may
still name a merged-away node, which a union-find (`parent`) resolves when a list is next read,
so a merge costs time in the merged node's degree only. Exactly one current entry exists per live
edge, so the merge order is the lexicographic `(cost, lo, hi)` order: ties break by the lower node
pair, deterministically.
"""

from __future__ import annotations

import heapq

import numpy as np
from numba.typed import List

from bayesian_fields_core.jit import compiled


@compiled
def _entropy(row: np.ndarray) -> float:
    """Shannon entropy in nats of one distribution; 0 log 0 = 0."""
    h = 0.0
    for v in row:
        if v > 0.0:
            h -= v * np.log(v)
    return h


@compiled
def _pair_cost(mass: np.ndarray, cond: np.ndarray, ent: np.ndarray, a: int, b: int) -> float:
    """`d_ab = (p_a + p_b) H(mix) - p_a H(a) - p_b H(b)`, clipped at 0 against rounding."""
    m_a, m_b = mass[a], mass[b]
    total = m_a + m_b
    h = 0.0
    for y in range(cond.shape[1]):
        v = (m_a * cond[a, y] + m_b * cond[b, y]) / total
        if v > 0.0:
            h -= v * np.log(v)
    cost = total * h - m_a * ent[a] - m_b * ent[b]
    return cost if cost > 0.0 else 0.0


@compiled
def _find(parent: np.ndarray, x: int) -> int:
    """Surviving node that `x` was merged into (union-find with path compression)."""
    root = x
    while parent[root] != root:
        root = parent[root]
    while parent[x] != root:
        nxt = parent[x]
        parent[x] = root
        x = nxt
    return root


@compiled
def greedy_merges(
    mass: np.ndarray,
    cond: np.ndarray,
    indptr: np.ndarray,
    indices: np.ndarray,
    edges: np.ndarray,
    information: float,
    delta: float,
    tiny: float,
) -> tuple[np.ndarray, np.ndarray, float]:
    """Merge greedily until the next merge's relative loss exceeds `delta`.

    mass (P,) and cond (P, Y) are updated in place. indptr/indices: the symmetric adjacency in
    CSR form; edges (E, 2): each edge once, `lo < hi`. Returns (merges (K, 2), costs (K,),
    relative loss of the refused merge, or inf when the edges ran out).
    """
    num = mass.shape[0]
    ent = np.empty(num)
    for k in range(num):
        ent[k] = _entropy(cond[k])
    parent = np.arange(num)
    version = np.zeros(num, dtype=np.int64)
    mark = np.zeros(num, dtype=np.int64)
    stamp = 0
    neighbours = List()
    for k in range(num):
        neighbours.append(indices[indptr[k] : indptr[k + 1]].copy())

    heap = [(0.0, 0, 0, 0, 0)]
    heap.pop()
    for e in range(edges.shape[0]):
        lo, hi = edges[e, 0], edges[e, 1]
        heap.append((_pair_cost(mass, cond, ent, lo, hi), lo, hi, 0, 0))
    heapq.heapify(heap)

    merges = np.empty((max(num - 1, 0), 2), dtype=np.int64)
    costs = np.empty(max(num - 1, 0))
    done = 0
    stopped_at = np.inf
    while len(heap) > 0:
        cost, i, j, v_i, v_j = heapq.heappop(heap)
        if version[i] != v_i or version[j] != v_j:
            continue  # an endpoint merged since this entry was pushed
        if information > tiny:
            relative = cost / information
        else:
            relative = 0.0 if cost <= tiny else np.inf
        if relative > delta:
            stopped_at = relative
            break
        merges[done, 0], merges[done, 1] = i, j
        costs[done] = cost
        done += 1

        total = mass[i] + mass[j]
        for y in range(cond.shape[1]):
            cond[i, y] = (mass[i] * cond[i, y] + mass[j] * cond[j, y]) / total
        mass[i] = total
        mass[j] = 0.0
        ent[i] = _entropy(cond[i])
        parent[j] = i
        version[i] += 1
        version[j] += 1  # j's remaining entries are stale from now on

        # i's new neighbourhood: both lists resolved through the union-find, deduplicated.
        stamp += 1
        mark[i] = stamp
        union = np.empty(neighbours[i].shape[0] + neighbours[j].shape[0], dtype=np.int64)
        count = 0
        for side in (i, j):
            for x in neighbours[side]:
                r = _find(parent, x)
                if mark[r] != stamp:
                    mark[r] = stamp
                    union[count] = r
                    count += 1
        neighbours[i] = union[:count].copy()
        neighbours[j] = np.empty(0, dtype=np.int64)
        for m in neighbours[i]:
            lo, hi = (i, m) if i < m else (m, i)
            heapq.heappush(heap, (_pair_cost(mass, cond, ent, lo, hi), lo, hi, version[lo], version[hi]))
    return merges[:done], costs[:done], stopped_at
