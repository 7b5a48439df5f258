"""Speed and tightness of `minimum_obb` and speed of the exact `obb_iou`.

Prints, per point count, the median time of `minimum_obb` on points filling a randomly rotated box
and on points on a rotated cylinder's surface (every point on the hull: the hard case), and the
median ratio of the box volume to the best of 20,000 random orientations (below 1 = tighter than
brute force; n/a when the hull is too large for the brute force). Then the median time of one `obb_iou` of two overlapping rotated boxes.

Run: .venv/bin/python bench/bench_obb.py
"""

from __future__ import annotations

import statistics
import time

import numpy as np
from scipy.spatial import ConvexHull
from scipy.spatial.transform import Rotation

from bayesian_fields_core.eval.box_iou import obb_iou
from bayesian_fields_core.geometry.obb import minimum_obb


def brute_force_volume(points: np.ndarray, n: int = 20_000) -> float:
    """Smallest box volume over n random orientations (nan when the hull is too big to try)."""
    hull = points[ConvexHull(points).vertices]
    if len(hull) > 5_000:
        return float("nan")
    rots = Rotation.random(n, random_state=0).as_matrix()
    best = np.inf
    for start in range(0, n, 500):
        local = np.einsum("vk,nkj->nvj", hull, rots[start : start + 500])
        best = min(best, float(np.prod(np.ptp(local, axis=1), axis=1).min()))
    return best


def shapes(rng: np.random.Generator, n: int) -> dict[str, np.ndarray]:
    rot = Rotation.random(random_state=int(rng.integers(1 << 30))).as_matrix()
    box = ((rng.random((n, 3)) - 0.5) * [0.6, 0.3, 0.1]) @ rot.T
    a = rng.random(n) * 2 * np.pi
    cyl = np.c_[0.1 * np.cos(a), 0.1 * np.sin(a), rng.random(n) * 0.3] @ rot.T
    return {"box": box, "cylinder surface": cyl}


def main() -> None:
    rng = np.random.default_rng(0)
    for n in (1_000, 10_000, 100_000):
        for name in ("box", "cylinder surface"):
            times, ratios = [], []
            for _ in range(5):
                pts = shapes(rng, n)[name]
                t0 = time.perf_counter()
                obb = minimum_obb(pts)
                times.append(time.perf_counter() - t0)
                ratios.append(obb.volume / brute_force_volume(pts))
            print(
                f"minimum_obb n={n:>7d} {name:17s} median {statistics.median(times) * 1000:7.1f} ms"
                f"  volume / brute force {statistics.median(ratios):.3f}"
            )
    a = minimum_obb(shapes(rng, 1000)["box"])
    b = minimum_obb(shapes(rng, 1000)["box"] + 0.05)
    times = []
    for _ in range(200):
        t0 = time.perf_counter()
        obb_iou(a, b)
        times.append(time.perf_counter() - t0)
    print(f"obb_iou median {statistics.median(times) * 1000:.2f} ms (IoU {obb_iou(a, b):.3f})")


if __name__ == "__main__":
    main()
