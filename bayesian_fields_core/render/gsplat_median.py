"""Median depth on the gsplat path, from gsplat's own front-to-back traversal.

gsplat's `rasterization()` renders expected depth ("ED") but has no median-depth mode for 3D
Gaussians (only `rasterization_2dgs` has one, for a different primitive). What it does expose is
the traversal itself: `rasterize_to_indices_in_range(range_start, range_end, transmittances, ...)`
returns, for a range of per-tile batches, every (Gaussian, pixel) pair that contributes, in the
same depth order and with the same culling, alpha rule and early stop as its rasteriser; gsplat's
own reference compositor (`gsplat.cuda._torch_impl._rasterize_to_pixels`) is built on it. So the
median is found here, on the GPU, from the projection `rasterization()` already computed (its
`meta`, rendered with `packed=False`): recompute each pair's alpha, accumulate transmittance per
pixel in log space, and record the depth of the Gaussian whose inclusion drops it below the
median level. Pixels that have crossed get transmittance 0 for the next range, so gsplat skips
them, and the loop ends when every pixel has crossed or every tile's list is exhausted.

The kernel call is injected (`indices_fn`) so the whole loop runs under test on the CPU with a
torch enumeration of the same pairs; on a worker it is `gsplat.rasterize_to_indices_in_range`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import torch

IndicesFn = Callable[..., tuple[torch.Tensor, torch.Tensor, torch.Tensor]]


def pair_alphas(
    means2d: torch.Tensor,
    conics: torch.Tensor,
    opacities: torch.Tensor,
    gaussian_ids: torch.Tensor,
    pixel_ids: torch.Tensor,
    width: int,
    max_alpha: float,
) -> torch.Tensor:
    """(M,) alpha of each (Gaussian, pixel) pair, gsplat's rule: min(max_alpha, o exp(-sigma)).

    means2d (N, 2) pixels, conics (N, 3) upper triangle (a, b, c) of the inverse 2D covariance,
    opacities (N,); pixel ids are row-major and the pixel centre is at (u + 0.5, v + 0.5), with
    sigma = 0.5 (a dx^2 + c dy^2) + b dx dy.
    """
    px = (pixel_ids % width).to(means2d.dtype) + 0.5
    py = torch.div(pixel_ids, width, rounding_mode="floor").to(means2d.dtype) + 0.5
    dx = means2d[gaussian_ids, 0] - px
    dy = means2d[gaussian_ids, 1] - py
    c = conics[gaussian_ids]
    sigma = 0.5 * (c[:, 0] * dx * dx + c[:, 2] * dy * dy) + c[:, 1] * dx * dy
    return (opacities[gaussian_ids] * torch.exp(-sigma)).clamp_max(max_alpha)


def accumulate_median(
    pixel_ids: torch.Tensor,
    alphas: torch.Tensor,
    depths: torch.Tensor,
    transmittance: torch.Tensor,
    median: torch.Tensor,
    level: float,
) -> None:
    """Fold one range of pairs into `transmittance` and `median` (both (H*W,), in place).

    pixel_ids, alphas, depths: (M,) pairs, each pixel's pairs in front-to-back order (gsplat
    writes them per pixel in traversal order; a stable sort by pixel keeps that order). A pixel's
    median is the depth of the pair after which its transmittance first drops below `level`.
    """
    if pixel_ids.numel() == 0:
        return
    pix, order = torch.sort(pixel_ids, stable=True)
    log_keep = torch.log1p(-alphas[order].double())  # (M,) log(1 - alpha), float64 sums
    z = depths[order]
    csum = torch.cumsum(log_keep, 0)
    first = torch.ones_like(pix, dtype=torch.bool)
    first[1:] = pix[1:] != pix[:-1]
    segment = torch.cumsum(first.long(), 0) - 1
    base = (csum - log_keep)[first][segment]  # cumulative sum before each pixel's first pair
    t_in = transmittance[pix].double()
    t_after = t_in * torch.exp(csum - base)
    t_before = t_in * torch.exp(csum - base - log_keep)
    crossed = (t_before >= level) & (t_after < level)  # at most one pair per pixel: T decreases
    median[pix[crossed]] = z[crossed].to(median.dtype)
    transmittance.scatter_reduce_(0, pix, t_after.to(transmittance.dtype), reduce="amin")


def _num_batches(isect_offsets: torch.Tensor, n_isects: int, block_size: int) -> int:
    """How many per-tile batches the longest tile list needs (gsplat's batch = one tile's pixels)."""
    flat = torch.cat([isect_offsets.flatten(), torch.tensor([n_isects], device=isect_offsets.device)])
    longest = int((flat[1:] - flat[:-1]).max().item()) if flat.numel() > 1 else 0
    return (longest + block_size - 1) // block_size


def median_depth_from_meta(
    meta: Mapping[str, Any],
    width: int,
    height: int,
    *,
    level: float,
    max_alpha: float,
    indices_fn: IndicesFn,
    batches_per_call: int = 4,
) -> torch.Tensor:
    """(H, W) median depth of one camera, 0 where transmittance never drops below `level`.

    meta: gsplat's `rasterization(..., packed=False)` metadata for one camera: "means2d"
        (1, N, 2), "conics" (1, N, 3), "opacities" (1, N), "depths" (1, N), "isect_offsets"
        (1, tiles_y, tiles_x), "flatten_ids" (n_isects,), "tile_size".
    indices_fn: `gsplat.rasterize_to_indices_in_range` (or an equivalent enumerator).
    batches_per_call: per-tile batches per kernel call; the median usually lies in the first.
    """
    means2d = meta["means2d"].reshape(-1, 2)
    conics = meta["conics"].reshape(-1, 3)
    opacities = meta["opacities"].reshape(-1)
    depths = meta["depths"].reshape(-1)
    tile_size = int(meta["tile_size"])
    offsets = meta["isect_offsets"]
    flatten_ids = meta["flatten_ids"]
    device = means2d.device
    transmittance = torch.ones(height * width, device=device)
    median = torch.zeros(height * width, device=device)
    n_batches = _num_batches(offsets, int(flatten_ids.numel()), tile_size * tile_size)
    for step in range(0, n_batches, batches_per_call):
        pending = transmittance >= level
        if not bool(pending.any()):
            break
        # Crossed pixels get T = 0: the kernel's early stop then skips them entirely.
        t_in = torch.where(pending, transmittance, torch.zeros_like(transmittance))
        gs_ids, pixel_ids, _image_ids = indices_fn(
            step,
            step + batches_per_call,
            t_in.reshape(1, height, width),
            meta["means2d"],
            meta["conics"],
            meta["opacities"],
            width,
            height,
            tile_size,
            offsets,
            flatten_ids,
        )
        pixel_ids = pixel_ids.long() % (height * width)  # camera 0 only: strip any image offset
        gs_ids = gs_ids.long()
        alphas = pair_alphas(means2d, conics, opacities, gs_ids, pixel_ids, width, max_alpha)
        # Only pending pixels appear (T_in = 0 elsewhere), and they continue from T.
        accumulate_median(pixel_ids, alphas, depths[gs_ids], transmittance, median, level)
    return median.reshape(height, width)
