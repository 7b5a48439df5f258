"""Bytes of a result (docs/results-format.md) at the scale of the paper's memory table.

The paper's Apartment map (Table 5): ~400,000 Gaussians, 1,108 primitives, 37 objects; its semantic
map takes 3.05 MB (Gaussian ids 3.04, object probabilities 0.002, cluster ids 0.0001). This script
builds a synthetic map of that size (primitives = Voronoi cells of 1,108 seeds, 37 objects made of
primitives, the remaining primitives pruned), writes it with `write_result` to a temporary
LocalStore, and prints the stored bytes of each part, for two Gaussian orders: random (the worst
case for the compressor) and sorted along a space-filling order (what a splat trainer's output
roughly looks like after densification clones neighbours next to each other). It repeats each
write and reports the median write time.

Run: .venv/bin/python bench/bench_results_size.py [--gaussians 400000] [--repeats 5]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time

import numpy as np
from scipy.spatial import cKDTree

from bayesian_fields_core.geometry.obb import minimum_obb
from bayesian_fields_core.job.store import LocalStore
from bayesian_fields_core.results import Result, SelectedObject, result_sizes, write_result


def synthetic_map(num_gaussians: int, num_primitives: int, num_objects: int, order: str, seed: int = 0):
    rng = np.random.default_rng(seed)
    means = rng.random((num_gaussians, 3)) * [8.0, 6.0, 2.5]
    if order == "spatial":
        cell = np.floor(means / 0.05).astype(np.int64)
        means = means[np.lexsort((cell[:, 2], cell[:, 1], cell[:, 0]))]
    seeds = rng.random((num_primitives, 3)) * [8.0, 6.0, 2.5]
    primitive_ids = cKDTree(seeds).query(means)[1].astype(np.int64)
    # 37 objects of 1-6 primitives each; the other primitives belong to pruned objects
    groups = np.array_split(rng.permutation(num_primitives)[: num_objects * 4], num_objects)
    prim_to_obj = np.full(num_primitives, -1, dtype=np.int64)
    for oid, group in enumerate(groups):
        prim_to_obj[group] = oid
    object_ids = prim_to_obj[primitive_ids]
    tasks = [f"task {i}" for i in range(10)]
    probs = rng.dirichlet(np.ones(len(tasks) + 1), size=num_objects).astype(np.float32)
    selections = {}
    for t, task in enumerate(tasks):
        objs = []
        for oid in np.argsort(-probs[:, t])[:3]:
            pts = means[object_ids == oid]
            objs.append(
                SelectedObject(int(oid), float(probs[oid, t]), len(pts), pts.mean(0), minimum_obb(pts))
            )
        selections[task] = objs
    return Result(tasks, object_ids, probs, selections, primitive_ids=primitive_ids)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--gaussians", type=int, default=400_000)
    parser.add_argument("--primitives", type=int, default=1108)
    parser.add_argument("--objects", type=int, default=37)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    paper_mb = {"object_ids.bin": 3.04, "probabilities.bin": 0.002, "total/object_map": 3.05}
    for order in ("random", "spatial"):
        result = synthetic_map(args.gaussians, args.primitives, args.objects, order)
        times = []
        with tempfile.TemporaryDirectory() as tmp:
            store = LocalStore(tmp)
            for _ in range(args.repeats):
                t0 = time.perf_counter()
                write_result(store, "r", result)
                times.append(time.perf_counter() - t0)
            sizes = result_sizes(store, "r")
        print(
            f"\n{order} Gaussian order: {args.gaussians} Gaussians, {args.primitives} primitives, "
            f"{args.objects} objects, {int((result.object_ids >= 0).sum())} Gaussians in objects"
        )
        print(f"{'part':24s} {'bytes':>10s} {'MB':>9s} {'paper MB':>9s}")
        for key, size in sizes.items():
            paper = paper_mb.get(key)
            print(f"{key:24s} {size:10d} {size / 1e6:9.4f} {'' if paper is None else f'{paper:9.3f}'}")
        print(f"write_result median {statistics.median(times) * 1000:.0f} ms over {args.repeats} runs")


if __name__ == "__main__":
    main()
