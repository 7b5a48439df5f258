"""Cost of the clustering's per-view conditionals (issue 23) against the paper's fused ones.

`primitive_scores` (METHOD step 7) on a synthetic map: N Gaussians, T tasks, P primitives, fused
log-odds from up to 60 views. 'fused' averages the fused probabilities per primitive; 'per_view'
also computes each Gaussian's per-view probability (one (N, T) expit) and averages it and the
view counts. Prints the median wall time of each over --repeats and their ratio.
Usage: python bench/bench_conditionals.py [--gaussians 1000000] [--tasks 26] [--primitives 3000]
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
from scipy.special import expit

from bayesian_fields_core.objects.clustering import primitive_scores
from bayesian_fields_core.params import PipelineParams


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--gaussians", type=int, default=1_000_000)
    parser.add_argument("--tasks", type=int, default=26)
    parser.add_argument("--primitives", type=int, default=3000)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    n, t = args.gaussians, args.tasks
    views = rng.integers(0, 60, size=n).astype(np.int32)
    logodds = (-2.2 + views[:, None] * rng.normal(-1.0, 3.0, size=(n, t))).astype(np.float32)
    probabilities = expit(logodds).astype(np.float32)
    primitive_ids = rng.integers(-1, args.primitives, size=n).astype(np.int32)
    seconds: dict[str, list[float]] = {"fused": [], "per_view": []}
    for _ in range(args.repeats):
        for mode in seconds:
            params = PipelineParams(aib_conditionals=mode)  # type: ignore[arg-type]
            t0 = time.perf_counter()
            primitive_scores(primitive_ids, probabilities, logodds, params, views)
            seconds[mode].append(time.perf_counter() - t0)
    med = {mode: statistics.median(s) for mode, s in seconds.items()}
    print(f"{n:,} Gaussians x {t} tasks, {args.primitives:,} primitives, median of {args.repeats}:")
    for mode, value in med.items():
        print(f"  primitive_scores, {mode:<8}: {value:.3f} s")
    print(
        f"  per_view / fused: {med['per_view'] / med['fused']:.2f}x (+{med['per_view'] - med['fused']:.3f} s)"
    )


if __name__ == "__main__":
    main()
