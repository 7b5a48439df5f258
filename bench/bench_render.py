"""Benchmark the torch Gaussian renderer on the CPU (prints absolute figures and medians).

Scenes are random Gaussians filling a box in front of the camera with surface-splat-like sizes
(1-5 cm, scaled so 1M Gaussians give a depth complexity similar to a real capture).
Usage: python bench/bench_render.py [--n 100000] [--width 640 --height 480] [--repeats 5]
       [--large]  (also 1M Gaussians at 1280x720: time and peak RSS) [--threads T]
"""

from __future__ import annotations

import argparse
import resource
import statistics
import time

import numpy as np
import torch

from bayesian_fields_core.render import GaussianRenderer
from bayesian_fields_core.scene.types import Gaussians


def random_scene(n: int, seed: int = 0) -> Gaussians:
    """n Gaussians in a 4 x 3 x 4 m box 1-5 m in front of an identity camera, SH degree 3."""
    rng = np.random.default_rng(seed)
    means = rng.uniform([-2.0, -1.5, 1.0], [2.0, 1.5, 5.0], size=(n, 3)).astype(np.float32)
    size = 0.03 * (1e5 / n) ** (1 / 3)  # keep coverage comparable when n changes
    log_scales = np.log(rng.uniform(0.3, 1.5, size=(n, 3)) * size).astype(np.float32)
    quats = rng.normal(size=(n, 4)).astype(np.float32)
    opacity_logits = rng.normal(0.0, 2.0, size=n).astype(np.float32)
    sh = (rng.normal(size=(n, 16, 3)) * 0.3).astype(np.float32)
    return Gaussians(means, log_scales, quats, opacity_logits, sh)


def camera(width: int, height: int) -> np.ndarray:
    f = 0.8 * width
    return np.array([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1.0]])


def time_frames(r: GaussianRenderer, width: int, height: int, repeats: int, depth_only: bool) -> list[float]:
    K = camera(width, height)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        r.render(K, np.eye(4), width, height, depth_only=depth_only)
        times.append(time.perf_counter() - t0)
    return times


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--n", type=int, default=100_000)
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=480)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--large", action="store_true", help="also 1M Gaussians at 1280x720")
    ap.add_argument("--threads", type=int, default=0, help="torch intra-op threads (0: torch default)")
    args = ap.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    print(f"torch {torch.__version__}, threads={torch.get_num_threads()}")

    r = GaussianRenderer(random_scene(args.n), device="cpu", backend="torch")
    for depth_only in (False, True):
        times = time_frames(r, args.width, args.height, args.repeats, depth_only)
        label = "depth-only" if depth_only else "rgb+depth "
        print(
            f"{args.n} Gaussians {args.width}x{args.height} {label}: median {statistics.median(times):.3f} s "
            f"(min {min(times):.3f}, max {max(times):.3f}, {args.repeats} frames)"
        )

    if args.large:
        n, w, h = 1_000_000, 1280, 720
        big = GaussianRenderer(random_scene(n, seed=1), device="cpu", backend="torch")
        for depth_only in (False, True):
            times = time_frames(big, w, h, 2, depth_only)
            label = "depth-only" if depth_only else "rgb+depth "
            print(f"{n} Gaussians {w}x{h} {label}: median {statistics.median(times):.3f} s")
        # ru_maxrss is the process high-water mark (KiB on Linux): the 1M scene dominates it.
        rss_peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        print(f"peak RSS of the whole run (scene arrays + renderer + frames): {rss_peak:.0f} MiB")


if __name__ == "__main__":
    main()
