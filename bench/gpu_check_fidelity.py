"""Fidelity of our torch rasteriser against gsplat on one splat and its cameras (for gpu_check).

Our renderer (`render/`, torch) had only been compared with its own images; gsplat is the CUDA
rasteriser a GPU worker renders with. Here both render the same frames and what fusion reads
from them is compared step by step: colour (PSNR), expected and median depth (over pixels both
render: median absolute difference, 90th percentile relative difference, share within the
visibility tolerance; and pixels only one of them renders), the mask-to-Gaussian associations
made from each one's median depth with the same masks (Jaccard of the (Gaussian, mask) pairs),
and the log-odds fused from each set of associations with the same scores (the pipeline's
`fusion` code on both sides). On a CPU gpu_check runs this with our renderer on both sides, which
exercises every line of it and must report perfect agreement.

A renderer here is anything with `render_tensors(K, world_to_camera, width, height)` returning
(rgb (H, W, 3), expected depth, median depth, alpha (H, W)) tensors, as `GaussianRenderer` does.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
from scipy.special import logit

from bayesian_fields_core.fusion.state import FusionSettings, FusionState
from bayesian_fields_core.fusion.visibility import centre_columns, mask_associations

Scores = Callable[[int], tuple[np.ndarray, np.ndarray]]
"""Frame index -> (labels (H, W) int32, cosine scores (M, T) float32 of its masks)."""


def psnr(a: torch.Tensor, b: torch.Tensor) -> float:
    """Peak signal-to-noise ratio in dB of two images in [0, 1]; inf when they are equal."""
    mse = float(torch.mean((a.double() - b.double()) ** 2))
    return math.inf if mse == 0.0 else 10.0 * math.log10(1.0 / mse)


def pair_keys(gaussian_ids: torch.Tensor, mask_ids: torch.Tensor, num_masks: int) -> torch.Tensor:
    """One int64 key per (Gaussian, mask) pair: `gaussian * num_masks + mask`."""
    return gaussian_ids.long() * num_masks + mask_ids.long()


def jaccard(a: torch.Tensor, b: torch.Tensor) -> tuple[int, int]:
    """(|A & B|, |A | B|) of two 1-D tensors of distinct keys."""
    both = int(torch.isin(a, b).sum())
    return both, int(a.numel() + b.numel() - both)


@dataclass
class DepthDiffs:
    """Pixel-wise depth differences gathered over frames (host arrays, one entry per pixel)."""

    abs_diff: list[np.ndarray] = field(default_factory=list)
    rel_diff: list[np.ndarray] = field(default_factory=list)
    within: list[np.ndarray] = field(default_factory=list)
    only_one: int = 0
    pixels: int = 0

    def add(self, a: torch.Tensor, b: torch.Tensor, tolerance: float, relative: float) -> None:
        """Compare depth images a (reference) and b (H, W); 0 = nothing rendered there."""
        has_a, has_b = a > 0, b > 0
        both = has_a & has_b
        da, db = a[both].double(), b[both].double()
        diff = (da - db).abs()
        self.abs_diff.append(diff.cpu().numpy())
        self.rel_diff.append((diff / da).cpu().numpy())
        self.within.append((diff <= tolerance + relative * da).cpu().numpy())
        self.only_one += int((has_a ^ has_b).sum())
        self.pixels += a.numel()

    def summary(self) -> dict[str, float]:
        diff = np.concatenate(self.abs_diff) if self.abs_diff else np.zeros(0)
        rel = np.concatenate(self.rel_diff) if self.rel_diff else np.zeros(0)
        within = np.concatenate(self.within) if self.within else np.zeros(0, bool)
        empty = diff.size == 0
        return {
            "pixels_both": int(diff.size),
            "only_one_share": self.only_one / max(self.pixels, 1),
            "median_abs": math.nan if empty else float(np.median(diff)),
            "p90_rel": math.nan if empty else float(np.percentile(rel, 90)),
            "within_tolerance": math.nan if empty else float(within.mean()),
        }


@dataclass
class Fidelity:
    """The figures of one comparison (reference = our torch rasteriser)."""

    frames: int
    psnr_db: list[float]
    expected_depth: dict[str, float]
    median_depth: dict[str, float]
    pairs: dict[str, float]
    logodds: dict[str, float]

    def as_dict(self) -> dict[str, Any]:
        finite = [p for p in self.psnr_db if math.isfinite(p)]
        return {
            "frames": self.frames,
            "psnr_db_median": float(np.median(self.psnr_db)) if self.psnr_db else math.nan,
            "psnr_db_min": min(self.psnr_db) if self.psnr_db else math.nan,
            "psnr_frames_identical": len(self.psnr_db) - len(finite),
            "expected_depth": self.expected_depth,
            "median_depth": self.median_depth,
            "pairs": self.pairs,
            "logodds": self.logodds,
        }


def logodds_agreement(a: np.ndarray, b: np.ndarray, start: float) -> dict[str, float]:
    """How two fused (N, T) log-odds states agree: over Gaussians either one moved off the prior
    `start`, the largest and mean absolute difference, the share whose best task is the same, and
    the share whose sign of evidence per (Gaussian, task) is the same."""
    moved = np.any(a != start, axis=1) | np.any(b != start, axis=1)
    if not moved.any():
        return {"gaussians": 0, "max_abs": 0.0, "mean_abs": 0.0, "top_task_same": 1.0, "sign_same": 1.0}
    da, db = a[moved].astype(np.float64), b[moved].astype(np.float64)
    diff = np.abs(da - db)
    return {
        "gaussians": int(moved.sum()),
        "max_abs": float(diff.max()),
        "mean_abs": float(diff.mean()),
        "top_task_same": float(np.mean(da.argmax(axis=1) == db.argmax(axis=1))),
        "sign_same": float(np.mean((da > start) == (db > start))),
    }


def compare_renderers(
    frames: Iterable[tuple[int, Any]],
    reference: Any,
    candidate: Any,
    means: np.ndarray,
    scores: Scores,
    settings: FusionSettings,
    *,
    num_tasks: int,
    depth_tolerance: float,
    relative_tolerance: float,
    near: float,
    device: torch.device | str,
) -> Fidelity:
    """Render every (index, frame) with both renderers and compare what fusion reads from them.

    means: (N, 3) Gaussian centres of the splat both render; `scores` gives each frame's labels
    and its masks' scores against `num_tasks` tasks. The associations use each one's median depth
    (the pipeline's default `depth_source`) and the frame's labels; both fusion states get the
    same scores, so the log-odds differ only through the associations.
    """
    device = torch.device(device)
    centres = centre_columns(means, device)
    states = [FusionState(len(means), num_tasks, settings, device) for _ in range(2)]
    expected, median = DepthDiffs(), DepthDiffs()
    psnrs: list[float] = []
    inter = union = 0
    count = 0
    for index, frame in frames:
        labels, phi = scores(index)
        keys, renders = [], []
        for renderer, state in zip((reference, candidate), states, strict=True):
            rgb, depth, med, _alpha = renderer.render_tensors(
                frame.K, frame.world_to_camera, frame.width, frame.height
            )
            renders.append((rgb, depth.to(device), med.to(device)))
            gids, mids = mask_associations(
                centres,
                frame.K,
                frame.world_to_camera,
                frame.width,
                frame.height,
                med,
                labels,
                depth_tolerance=depth_tolerance,
                relative_tolerance=relative_tolerance,
                near=near,
            )
            state.add_frame(gids, mids, phi)
            keys.append(pair_keys(gids, mids, max(len(phi), 1)))
        (rgb_a, depth_a, med_a), (rgb_b, depth_b, med_b) = renders
        psnrs.append(psnr(rgb_a, rgb_b.to(rgb_a.device)))
        expected.add(depth_a, depth_b, depth_tolerance, relative_tolerance)
        median.add(med_a, med_b, depth_tolerance, relative_tolerance)
        both, either = jaccard(keys[0], keys[1])
        inter, union = inter + both, union + either
        count += 1
    fused = [state.finish() for state in states]
    start = float(np.float32(logit(settings.prior)))  # the states' starting value, exactly
    return Fidelity(
        frames=count,
        psnr_db=psnrs,
        expected_depth=expected.summary(),
        median_depth=median.summary(),
        pairs={"jaccard": inter / union if union else 1.0, "union": union},
        logodds=logodds_agreement(fused[0].logodds, fused[1].logodds, start),
    )


def report_lines(fid: Fidelity) -> list[str]:
    """The printed figures, one line per quantity."""
    d = fid.as_dict()

    def depth(name: str, s: dict[str, float]) -> str:
        return (
            f"  {name:<15} median |diff| {s['median_abs']:.4g}, p90 rel {s['p90_rel']:.3g}, "
            f"within tolerance {100 * s['within_tolerance']:.2f} % of {s['pixels_both']:,} px; "
            f"rendered by one only {100 * s['only_one_share']:.2f} % of pixels"
        )

    lo = d["logodds"]
    return [
        f"  RGB PSNR        median {d['psnr_db_median']:.2f} dB, worst {d['psnr_db_min']:.2f} dB "
        f"over {d['frames']} frames ({d['psnr_frames_identical']} identical)",
        depth("expected depth", d["expected_depth"]),
        depth("median depth", d["median_depth"]),
        f"  associations    Jaccard {d['pairs']['jaccard']:.4f} of {d['pairs']['union']:,} (Gaussian, mask) pairs",
        f"  fused log-odds  max |diff| {lo['max_abs']:.4g}, mean {lo['mean_abs']:.4g} over {lo['gaussians']:,} "
        f"Gaussians with evidence; best task same {100 * lo['top_task_same']:.2f} %, "
        f"evidence sign same {100 * lo['sign_same']:.2f} %",
    ]
