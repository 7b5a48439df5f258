"""The AIB loop's heap compaction (`aib_kernel._compact`) drops exactly the stale entries and keeps
a valid heap, and compacting as often as possible changes neither the merges, their costs nor the
refused loss compared with never compacting."""

from __future__ import annotations

import numpy as np
import pytest

from bayesian_fields_core.objects.aib import adjacency_lists, mutual_information
from bayesian_fields_core.objects.aib_kernel import _compact, greedy_merges
from bayesian_fields_core.objects.edges import unique_pairs


def test_compact_keeps_the_current_entries_in_heap_order() -> None:
    rng = np.random.default_rng(1)
    num, size = 50, 400
    version = rng.integers(0, 3, num)
    lo = rng.integers(0, num - 1, size)
    hi = lo + 1 + rng.integers(0, num - 1 - lo)
    heap = np.stack(
        [rng.random(size).round(2), lo * num + hi, rng.integers(0, 3, size), rng.integers(0, 3, size)], axis=1
    ).astype(np.float64)
    current = (version[lo] == heap[:, 2]) & (version[hi] == heap[:, 3])
    assert 0 < current.sum() < size  # some stale entries to drop
    expected = sorted(map(tuple, heap[current]))
    kept = _compact(heap, size, version, num)
    assert sorted(map(tuple, heap[:kept])) == expected  # exactly the current entries, none lost
    for pos in range(1, kept):  # heap order on (cost, key)
        parent = (pos - 1) // 2
        assert (heap[parent, 0], heap[parent, 1]) <= (heap[pos, 0], heap[pos, 1])


@pytest.mark.slow
def test_compacting_often_gives_the_same_merges() -> None:
    rng = np.random.default_rng(7)
    num, tasks = 400, 6
    points = rng.random((num, 2))
    dist = np.linalg.norm(points[:, None] - points[None], axis=2)
    edges = unique_pairs(np.argwhere((dist < 0.12) & (dist > 0)), num)
    pyx = rng.dirichlet(np.full(tasks, 30.0), num)  # near-uniform rows: many cheap merges
    px = np.full(num, 1.0 / num)
    indptr, indices = adjacency_lists(edges, num)
    info = mutual_information(px, pyx)

    def run(compact_min: int) -> tuple[np.ndarray, np.ndarray, float]:
        return greedy_merges(
            px.copy(),
            pyx.copy(),
            indptr,
            indices,
            edges,
            info,
            0.5,
            1e-12,
            compact_min,
        )

    never = run(1 << 40)
    often = run(1)
    assert len(never[0]) > num // 2  # a long merge sequence, so the heap was compacted many times
    np.testing.assert_array_equal(often[0], never[0])
    np.testing.assert_array_equal(often[1], never[1])
    assert often[2] == never[2]
