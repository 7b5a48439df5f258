"""Benchmark per-frame fusion: visibility + likelihoods + Bayes update + primitives (torch ops).

Synthetic but shaped like a real capture: Gaussians on the walls of a 6 x 4 x 3 m room (plus a
share floating inside, which the depth test must reject), cameras inside looking around, a depth
image ray-cast analytically against the room box (standing in for the renderer, not timed),
Voronoi label images with ~100 exclusive masks (some pixels unlabelled), and cosine scores drawn
from the paper's score statistics (negatives ~ N(0.20, 0.015), one relevant task at +0.07 for
10 % of the masks)
so OR-phi accepts a realistic share of masks.
The fusion ops run on `--device` (default cpu) with the intra-op threads the fuse stage gives
them there (`fusion.tensors.fusion_threads`: one on the CPU) unless `--threads` is given; the
primitive builder runs on the host, as in the fuse stage.
Usage: python bench/bench_fusion.py [--gaussians 400000] [--frames 300] [--tasks 26] [--masks 100]
                                    [--device cpu|cuda] [--threads N]
Target: median < 0.5 s per frame at the defaults. Process-CPU time is printed beside the wall
time: on a shared machine the wall time includes waiting for a core.
"""

from __future__ import annotations

import argparse
import resource
import statistics
import time

import numpy as np
import torch

from bayesian_fields_core.fusion.bayes import bayes_update, init_logodds, probabilities
from bayesian_fields_core.fusion.likelihood import LikelihoodParams, log_likelihood_ratio
from bayesian_fields_core.fusion.tensors import fusion_threads, to_numpy
from bayesian_fields_core.fusion.visibility import centre_columns, mask_associations
from bayesian_fields_core.objects.primitives import PrimitiveBuilder

ROOM_LO = np.array([-3.0, -2.0, -1.5])
ROOM_HI = np.array([3.0, 2.0, 1.5])


def room_gaussians(n: int, rng: np.random.Generator, inside_share: float = 0.2) -> np.ndarray:
    """n centres: (1 - inside_share) on the walls (5 mm jitter), the rest inside the room."""
    n_in = int(n * inside_share)
    n_wall = n - n_in
    pts = rng.uniform(ROOM_LO, ROOM_HI, size=(n_wall, 3))
    axis = rng.integers(0, 3, size=n_wall)
    side = rng.integers(0, 2, size=n_wall)
    pts[np.arange(n_wall), axis] = np.where(side == 1, ROOM_HI[axis], ROOM_LO[axis])
    pts += rng.normal(0.0, 0.005, size=pts.shape)
    inside = rng.uniform(ROOM_LO * 0.8, ROOM_HI * 0.8, size=(n_in, 3))
    return np.vstack([pts, inside]).astype(np.float32)


def look_rotation(forward: np.ndarray) -> np.ndarray:
    """World-to-camera rotation for a camera looking along `forward` (OpenCV axes, y down)."""
    z = forward / np.linalg.norm(forward)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.stack([x, y, z])


def room_depth(K: np.ndarray, w2c: np.ndarray, width: int, height: int) -> np.ndarray:
    """Camera-z depth of the room's walls per pixel, by ray casting the box from inside."""
    u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    rays_cam = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], axis=-1)
    R, t = w2c[:3, :3], w2c[:3, 3]
    origin = -R.T @ t
    rays = rays_cam @ R  # world directions whose camera z component is 1
    with np.errstate(divide="ignore"):
        bound = np.where(rays > 0, ROOM_HI, ROOM_LO)
        hit = np.where(rays != 0, (bound - origin) / rays, np.inf)
    return hit.min(axis=-1).astype(np.float32)


def voronoi_labels(
    width: int, height: int, masks: int, rng: np.random.Generator, cell: int = 8
) -> np.ndarray:
    """Exclusive label image: Voronoi cells of `masks` seeds at 1/cell resolution, ~15 % unlabelled."""
    w, h = width // cell, height // cell
    seeds = rng.uniform([0, 0], [w, h], size=(masks, 2))
    yy, xx = np.mgrid[0:h, 0:w]
    d = (xx[..., None] - seeds[:, 0]) ** 2 + (yy[..., None] - seeds[:, 1]) ** 2
    small = d.argmin(axis=-1).astype(np.int32)
    small[np.isin(small, rng.choice(masks, size=masks * 15 // 100, replace=False))] = -1
    labels = np.repeat(np.repeat(small, cell, axis=0), cell, axis=1)
    present = np.unique(labels[labels >= 0])
    remap = np.full(masks, -1, dtype=np.int32)
    remap[present] = np.arange(present.size, dtype=np.int32)
    return np.where(labels >= 0, remap[np.maximum(labels, 0)], -1)


def synthetic_scores(
    masks: int, tasks: int, params: LikelihoodParams, rng: np.random.Generator
) -> np.ndarray:
    # Negatives spread like the paper's masked FastSAM segments (Fig. 2b: mean 0.20, std 0.015).
    phi = rng.normal(params.mu0, 0.015, size=(masks, tasks))
    relevant = rng.random(masks) < 0.1
    phi[relevant, rng.integers(0, tasks, size=int(relevant.sum()))] += params.mu1 - params.mu0
    return phi.astype(np.float32)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--gaussians", type=int, default=400_000)
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--tasks", type=int, default=26)
    ap.add_argument("--masks", type=int, default=100)
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=480)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--device", default="cpu", help="torch device of the fusion ops")
    ap.add_argument("--threads", type=int, help="torch intra-op threads (default: the fuse stage's)")
    args = ap.parse_args()
    threads = args.threads or fusion_threads(args.device)
    if threads:
        torch.set_num_threads(threads)

    rng = np.random.default_rng(args.seed)
    params = LikelihoodParams()
    means = room_gaussians(args.gaussians, rng)
    K = np.array([[0.8 * args.width, 0, args.width / 2], [0, 0.8 * args.width, args.height / 2], [0, 0, 1.0]])
    centres = centre_columns(means, args.device)  # once per job, as the fuse stage does
    logodds = init_logodds(args.gaussians, args.tasks, device=args.device)
    builder = PrimitiveBuilder(args.gaussians)

    parts: dict[str, list[float]] = {"visibility": [], "bayes": [], "primitives": [], "total": []}
    pairs, accepted_share, cpu = [], [], []
    for _ in range(args.frames):
        yaw = rng.uniform(0, 2 * np.pi)
        forward = np.array([np.cos(yaw), np.sin(yaw), rng.uniform(-0.4, 0.2)])
        w2c = np.eye(4)
        w2c[:3, :3] = look_rotation(forward)
        w2c[:3, 3] = -w2c[:3, :3] @ rng.uniform(ROOM_LO * 0.5, ROOM_HI * 0.5)
        depth = room_depth(K, w2c, args.width, args.height)
        labels = voronoi_labels(args.width, args.height, args.masks, rng)
        phi = synthetic_scores(int(labels.max()) + 1, args.tasks, params, rng)

        c0 = time.process_time()
        t0 = time.perf_counter()
        gids, mids = mask_associations(
            centres, K, w2c, args.width, args.height, depth, labels, depth_tolerance=0.05
        )
        t1 = time.perf_counter()
        accepted = to_numpy(bayes_update(logodds, gids, mids, log_likelihood_ratio(phi, params)))
        t2 = time.perf_counter()
        builder.add_frame(to_numpy(gids), to_numpy(mids), accepted)
        t3 = time.perf_counter()
        cpu.append(time.process_time() - c0)
        for key, value in zip(parts, (t1 - t0, t2 - t1, t3 - t2, t3 - t0), strict=True):
            parts[key].append(value)
        pairs.append(int(gids.shape[0]))
        accepted_share.append(float(accepted.mean()))

    t0 = time.perf_counter()
    probs = probabilities(to_numpy(logodds))
    ids = builder.primitive_ids
    t_final = time.perf_counter() - t0

    print(
        f"fusion bench: {args.gaussians:,} Gaussians, {args.frames} frames {args.width}x{args.height}, "
        f"~{args.masks} masks/frame, {args.tasks} tasks; torch on {args.device}, "
        f"{torch.get_num_threads()} intra-op thread(s)"
    )
    print(
        f"  visible (Gaussian, mask) pairs per frame: median {statistics.median(pairs):,.0f}; "
        f"masks accepted by OR-phi: {100 * statistics.mean(accepted_share):.0f} %"
    )
    for key, values in parts.items():
        arr = np.array(values) * 1e3
        print(
            f"  {key:<11} median {np.median(arr):7.1f} ms   p90 {np.percentile(arr, 90):7.1f} ms   "
            f"mean {arr.mean():7.1f} ms"
        )
    print(f"  total process CPU per frame: median {np.median(cpu) * 1e3:.1f} ms")
    print(
        f"  finalise (probabilities + compact ids): {t_final * 1e3:.1f} ms; "
        f"primitives: {int(ids.max()) + 1:,}; max p {float(probs.max()):.3f}"
    )
    print(f"  peak RSS {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MiB")
    print(f"  target: median total < 500 ms/frame -> {'OK' if np.median(parts['total']) < 0.5 else 'MISSED'}")


if __name__ == "__main__":
    main()
