"""Benchmark the cluster stage: primitive probabilities -> edges -> identical merge -> AIB ->
prune / top-k -> kNN filtering of the selected objects (CPU, numpy/scipy).

Synthetic map shaped like the paper's (400k Gaussians, ~2,000 primitives, 26 tasks): primitives
are blobs of Gaussian centres scattered through a 6 x 4 x 3 m room with log-normal extents (a few
large "wall/floor" ones overlap many), a third still exactly at the prior (the identical-merge
case), 5 % relevant to one task, the rest near the prior (std 0.003, so the AIB has merging to do); 1 % floaters per primitive
for the kNN filter.
Usage: python bench/bench_cluster.py [--gaussians 400000] [--primitives 2000] [--tasks 26]
       [--k 3] [--repeats 5]
Targets: AIB < 1 s on 2,000 primitives; whole stage < 10 s. Wall and process-CPU times are both
printed: on a shared machine the wall time includes waiting for a core.
"""

from __future__ import annotations

import argparse
import statistics
import time
import tracemalloc

import numpy as np

from bayesian_fields_core.objects.aib import aib
from bayesian_fields_core.objects.edges import merge_identical, overlap_edges
from bayesian_fields_core.objects.knn_filter import statistical_outlier_mask
from bayesian_fields_core.objects.probabilities import primitive_probabilities
from bayesian_fields_core.objects.select import object_probabilities, prune_mask, top_k


def synthetic_map(
    gaussians: int, primitives: int, tasks: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(means (N, 3) float32, primitive_ids (N,) int32, gaussian_probs (N, T) float32)."""
    ids = np.sort(rng.integers(0, primitives, size=gaussians)).astype(np.int32)
    ids[:primitives] = np.arange(primitives)  # every primitive non-empty
    ids = np.sort(ids)
    centres = rng.uniform([-3, -2, -1.5], [3, 2, 1.5], size=(primitives, 3))
    extents = np.exp(rng.normal(np.log(0.06), 0.6, size=(primitives, 3)))
    big = rng.choice(primitives, size=primitives // 100, replace=False)
    extents[big] *= 15.0
    means = centres[ids] + rng.normal(size=(gaussians, 3)) * extents[ids]
    floaters = rng.random(gaussians) < 0.01
    means[floaters] += rng.normal(0, 0.5, size=(int(floaters.sum()), 3))

    kind = rng.random(primitives)
    base = np.where(
        kind[:, None] < 0.33, 0.05, np.clip(rng.normal(0.05, 0.003, (primitives, tasks)), 0.001, 0.999)
    )
    relevant = kind > 0.95
    base[relevant, rng.integers(0, tasks, size=int(relevant.sum()))] = rng.uniform(
        0.6, 0.95, int(relevant.sum())
    )
    noise = rng.normal(0, 0.01, size=(gaussians, tasks)) * (kind[ids, None] >= 0.33)
    probs = np.clip(base[ids] + noise, 0.001, 0.999).astype(np.float32)
    return means.astype(np.float32), ids, probs


def run_once(means: np.ndarray, ids: np.ndarray, probs: np.ndarray, k: int, delta: float) -> dict[str, float]:
    times: dict[str, float] = {}
    t, c = time.perf_counter(), time.process_time()

    def lap(name: str) -> None:
        nonlocal t, c
        now, cpu = time.perf_counter(), time.process_time()
        times[name], times["cpu_" + name] = now - t, cpu - c
        t, c = now, cpu

    pyx = primitive_probabilities(ids, probs)
    lap("probabilities")
    edges = overlap_edges(means, ids)
    lap("edges")
    graph = merge_identical(pyx, edges)
    lap("merge_identical")
    result = aib(graph.pyx, graph.edges, delta, weights=graph.weights)
    lap("aib")
    object_of_primitive = result.labels[graph.labels]
    object_of_gaussian = object_of_primitive[ids]
    obj_pyx = object_probabilities(pyx, object_of_primitive)
    sizes = np.bincount(object_of_gaussian, minlength=obj_pyx.shape[0])
    keep = prune_mask(obj_pyx)
    chosen = top_k(obj_pyx, sizes, k=k, candidates=keep)
    lap("prune_select")
    selected = np.unique(chosen[chosen >= 0])
    order = np.argsort(object_of_gaussian, kind="stable")
    starts = np.searchsorted(object_of_gaussian[order], selected)
    ends = np.searchsorted(object_of_gaussian[order], selected, side="right")
    removed = 0
    for s, e in zip(starts, ends, strict=True):  # one KD-tree per selected object
        removed += int((~statistical_outlier_mask(means[order[s:e]])).sum())
    lap("knn")
    times["cpu_total"] = sum(v for k, v in times.items() if k.startswith("cpu_"))
    times["total"] = sum(v for k, v in times.items() if not k.startswith("cpu_"))
    times["_edges"] = edges.shape[0]
    times["_nodes"] = graph.pyx.shape[0]
    times["_node_edges"] = graph.edges.shape[0]
    times["_merges"] = result.merges.shape[0]
    times["_objects"] = obj_pyx.shape[0]
    times["_kept"] = int(keep.sum())
    times["_selected"] = selected.size
    times["_selected_gaussians"] = int((ends - starts).sum())
    times["_removed"] = removed
    return times


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--gaussians", type=int, default=400_000)
    ap.add_argument("--primitives", type=int, default=2_000)
    ap.add_argument("--tasks", type=int, default=26)
    ap.add_argument("--k", type=int, default=3)
    ap.add_argument("--delta", type=float, default=1e-5)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()

    means, ids, probs = synthetic_map(
        args.gaussians, args.primitives, args.tasks, np.random.default_rng(args.seed)
    )
    runs = [run_once(means, ids, probs, args.k, args.delta) for _ in range(args.repeats)]
    tracemalloc.start()
    run_once(means, ids, probs, args.k, args.delta)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()

    info = runs[0]
    print(
        f"cluster bench: {args.gaussians:,} Gaussians, {args.primitives:,} primitives, {args.tasks} tasks, "
        f"k={args.k}, {args.repeats} repeats"
    )
    print(
        f"  graph: {info['_edges']:,} overlap edges; after identical merge {info['_nodes']:,} nodes, "
        f"{info['_node_edges']:,} edges; AIB merges {info['_merges']:,} (delta {args.delta:g}); objects {info['_objects']:,}, kept after pruning {info['_kept']:,}, "
        f"selected {info['_selected']:,} ({info['_selected_gaussians']:,} Gaussians, {info['_removed']:,} "
        f"removed by kNN)"
    )
    for key in ("probabilities", "edges", "merge_identical", "aib", "prune_select", "knn", "total"):
        values = [r[key] * 1e3 for r in runs]
        cpu = statistics.median(r["cpu_" + key] * 1e3 for r in runs)
        print(
            f"  {key:<16} median {statistics.median(values):8.1f} ms   min {min(values):8.1f} ms   "
            f"(process CPU median {cpu:8.1f} ms)"
        )
    print(f"  peak traced memory of one run: {peak / 2**20:.0f} MiB")
    aib_ok = statistics.median(r["aib"] for r in runs) < 1.0
    total_ok = statistics.median(r["total"] for r in runs) < 10.0
    print(
        f"  targets: AIB < 1 s -> {'OK' if aib_ok else 'MISSED'}; total < 10 s -> {'OK' if total_ok else 'MISSED'}"
    )


if __name__ == "__main__":
    main()
