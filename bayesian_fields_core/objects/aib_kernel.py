"""The AIB's greedy merge loop, compiled with numba.

Why compiled: agglomeration is inherently sequential (each merge changes the costs the next one
is chosen from), so numpy can only vectorise inside one merge. At the paper's scale (thousands of
nodes, hundreds of thousands of edges, "background" clusters with thousands of neighbours) the
per-merge Python and numpy-call overhead dominated: 5-6 s for 8,500 nodes. The same algorithm as a
compiled loop takes a fraction of a second (`bench/bench_scale.py`).

Algorithm (`O(E log E)`): one binary heap (rows of a float64 array, sifted by hand: 3-4x faster
than `heapq` on numba tuples) holds an entry `(cost, lo, hi, version_lo, version_hi)` per edge; an entry is current while both endpoints keep the versions it was pushed with. Merging
the cheapest current edge folds `hi` into `lo` (the lower id survives and names the union), bumps
`lo`'s version (invalidating all its old entries), gives `lo` the union of both neighbourhoods and
pushes one fresh entry per neighbour. Stale entries are not searched for; once the heap has grown
by half since it was last cleaned, one sequential pass drops them all and re-heapifies (without
it, popping and discarding stale entries one by one was ~60 % of the loop). Neighbour lists of other nodes are not rewritten: they may
still name a merged-away node, which a union-find (`parent`) resolves when a list is next read,
so a merge costs time in the merged node's degree only. Exactly one current entry exists per live
edge, so the merge order is the lexicographic `(cost, lo, hi)` order: ties break by the lower node
pair, deterministically.

Edges that can never merge are not pushed. The loop only merges edges whose cost is at most
`limit = delta * I(X;Y)`, and Pinsker's inequality gives a lower bound on every cost that needs no
logarithm: with `m = pi_a a + pi_b b`, `KL(a || m) >= |a - m|_1^2 / 2` and `a - m = pi_b (a - b)`,
so `d_ab = (p_a + p_b) JS >= p_a p_b / (p_a + p_b) |a - b|_1^2 / 2`. An edge whose bound exceeds
the limit (with a margin far above float rounding) costs more than any merge still possible, so
leaving it out changes neither the merges nor their order; at the scale bench it spares ~65 % of
the cost evaluations (27 logarithms each) and heap entries. The refused merge's loss that is
reported (`stopped_at`) is then the minimum over the live edges, found in one final pass in which
the same bound again skips most exact evaluations.
"""

from __future__ import annotations

import numpy as np
from numba.typed import List

from bayesian_fields_core.compute.jit import compiled

_COMPACT_GROWTH = 1.5
"""The heap is compacted (`_compact`) once it holds this many times the entries it kept at the
last compaction: at the scale bench 1.5 took the loop from 0.39 to 0.25 s CPU (1.2: 0.28, 3: 0.39)."""
COMPACT_MIN = 1 << 14
"""Smallest heap ever compacted (a parameter of `greedy_merges` so a test can force compactions
on a small graph)."""


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
def _cost_bound(mass: np.ndarray, cond: np.ndarray, a: int, b: int) -> float:
    """Pinsker lower bound of `_pair_cost(a, b)`: `p_a p_b / (p_a + p_b) |c_a - c_b|_1^2 / 2`."""
    l1 = 0.0
    for y in range(cond.shape[1]):
        l1 += abs(cond[a, y] - cond[b, y])
    return 0.5 * (mass[a] * mass[b] / (mass[a] + mass[b])) * l1 * l1


@compiled
def _sift_down(heap: np.ndarray, size: int, pos: int) -> None:
    """Move the entry at `pos` down to its place (a hole sifted towards the leaves)."""
    cost, key, v_lo, v_hi = heap[pos, 0], heap[pos, 1], heap[pos, 2], heap[pos, 3]
    while True:
        child = 2 * pos + 1
        if child >= size:
            break
        right = child + 1
        if right < size and (
            heap[right, 0] < heap[child, 0]
            or (heap[right, 0] == heap[child, 0] and heap[right, 1] < heap[child, 1])
        ):
            child = right
        if heap[child, 0] < cost or (heap[child, 0] == cost and heap[child, 1] < key):
            heap[pos, 0], heap[pos, 1], heap[pos, 2], heap[pos, 3] = (
                heap[child, 0],
                heap[child, 1],
                heap[child, 2],
                heap[child, 3],
            )
            pos = child
        else:
            break
    heap[pos, 0], heap[pos, 1], heap[pos, 2], heap[pos, 3] = cost, key, v_lo, v_hi


@compiled
def _sift_up(heap: np.ndarray, pos: int) -> None:
    """Move the entry at `pos` up to its place."""
    cost, key, v_lo, v_hi = heap[pos, 0], heap[pos, 1], heap[pos, 2], heap[pos, 3]
    while pos > 0:
        parent = (pos - 1) >> 1
        if cost < heap[parent, 0] or (cost == heap[parent, 0] and key < heap[parent, 1]):
            heap[pos, 0], heap[pos, 1], heap[pos, 2], heap[pos, 3] = (
                heap[parent, 0],
                heap[parent, 1],
                heap[parent, 2],
                heap[parent, 3],
            )
            pos = parent
        else:
            break
    heap[pos, 0], heap[pos, 1], heap[pos, 2], heap[pos, 3] = cost, key, v_lo, v_hi


@compiled
def _compact(heap: np.ndarray, size: int, version: np.ndarray, num: int) -> int:
    """Drop the stale entries of `heap[:size]` (an endpoint merged since the push) and restore the
    heap order; returns the new size. Pops of stale entries were most of the loop's time (random
    accesses down a heap far larger than the cache); one sequential pass removes them in bulk."""
    kept = 0
    for a in range(size):
        key = int(heap[a, 1])
        i, j = key // num, key % num
        if version[i] == int(heap[a, 2]) and version[j] == int(heap[a, 3]):
            heap[kept, 0], heap[kept, 1], heap[kept, 2], heap[kept, 3] = (
                heap[a, 0],
                heap[a, 1],
                heap[a, 2],
                heap[a, 3],
            )
            kept += 1
    for pos in range(kept // 2 - 1, -1, -1):
        _sift_down(heap, kept, pos)
    return kept


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
    compact_min: int = COMPACT_MIN,
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

    # Costs above `limit` are never merged; a bound above `skip_above` proves a cost is. The
    # margin (1e-6 relative, 1e-12 absolute; masses sum to 1, so rounding in a cost is ~1e-14)
    # keeps float error in the bound or the cost from ever dropping a mergeable edge.
    limit = delta * information if information > tiny else tiny
    skip_above = limit * (1.0 + 1e-6) + 1e-12
    # The heap: rows (cost, lo * num + hi, version of lo, version of hi), ordered by the first
    # two, i.e. by (cost, lo, hi); ids and versions stay far below 2**53, so float64 holds them.
    heap = np.empty((max(2 * edges.shape[0], 16), 4))
    size = 0
    for e in range(edges.shape[0]):
        lo, hi = edges[e, 0], edges[e, 1]
        if _cost_bound(mass, cond, lo, hi) <= skip_above:
            heap[size, 0], heap[size, 1] = _pair_cost(mass, cond, ent, lo, hi), lo * num + hi
            heap[size, 2], heap[size, 3] = 0.0, 0.0
            size += 1
    for pos in range(size // 2 - 1, -1, -1):
        _sift_down(heap, size, pos)
    compact_at = max(int(_COMPACT_GROWTH * size), compact_min)

    merges = np.empty((max(num - 1, 0), 2), dtype=np.int64)
    costs = np.empty(max(num - 1, 0))
    done = 0
    refused = np.inf  # cost of the cheapest live edge not merged, once the loop ends
    while size > 0:
        cost, key, v_i, v_j = heap[0, 0], int(heap[0, 1]), int(heap[0, 2]), int(heap[0, 3])
        size -= 1
        if size > 0:
            heap[0, 0], heap[0, 1], heap[0, 2], heap[0, 3] = (
                heap[size, 0],
                heap[size, 1],
                heap[size, 2],
                heap[size, 3],
            )
            _sift_down(heap, size, 0)
        i, j = key // num, key % num
        if version[i] != v_i or version[j] != v_j:
            continue  # an endpoint merged since this entry was pushed
        if _relative(cost, information, tiny) > delta:
            refused = cost
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
            if _cost_bound(mass, cond, lo, hi) <= skip_above:
                if size == heap.shape[0]:
                    grown = np.empty((2 * size, 4))
                    grown[:size] = heap[:size]
                    heap = grown
                heap[size, 0], heap[size, 1] = _pair_cost(mass, cond, ent, lo, hi), lo * num + hi
                heap[size, 2], heap[size, 3] = version[lo], version[hi]
                _sift_up(heap, size)
                size += 1
        if size > compact_at:
            size = _compact(heap, size, version, num)
            compact_at = max(int(_COMPACT_GROWTH * size), compact_min)
    refused = _cheapest_live_edge(mass, cond, ent, parent, neighbours, refused)
    stopped_at = np.inf if refused == np.inf else _relative(refused, information, tiny)
    return merges[:done], costs[:done], stopped_at


@compiled
def _relative(cost: float, information: float, tiny: float) -> float:
    """A merge's loss relative to `I(X;Y)` (0 or inf when the information itself is ~0)."""
    if information > tiny:
        return cost / information
    return 0.0 if cost <= tiny else np.inf


@compiled
def _cheapest_live_edge(
    mass: np.ndarray, cond: np.ndarray, ent: np.ndarray, parent: np.ndarray, neighbours, best: float
) -> float:
    """min(best, the cost of every edge between surviving nodes): the loss of the merge the
    loop refused, including edges left out of the heap. The bound skips exact evaluations that
    cannot win (margin as for `skip_above`)."""
    for i in range(mass.shape[0]):
        if parent[i] != i:
            continue
        for x in neighbours[i]:
            m = _find(parent, x)
            if m <= i:
                continue  # each pair once, from its lower node
            if _cost_bound(mass, cond, i, m) > best * (1.0 + 1e-6) + 1e-12:
                continue
            cost = _pair_cost(mass, cond, ent, i, m)
            if cost < best:
                best = cost
    return best
