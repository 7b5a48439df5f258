"""The gsplat-path median depth, run on the CPU.

gsplat's kernels need CUDA, so `rasterize_to_indices_in_range` is stood in for here by a torch
enumeration of the same pairs with the kernel's documented rules (pixel centre +0.5, alpha =
min(0.99, o exp(-sigma)), skip alpha < 1/255 or sigma < 0, stop before T <= 1e-4, batches of
tile_size^2 entries of each tile's depth-sorted list, start from the given transmittance). The
meta it reads is built from this package's own projection and tile bins, so the loop in
`median_depth_from_meta` must reproduce the torch compositor's median.
"""

from __future__ import annotations

import numpy as np
import torch

from bayesian_fields_core.render import GaussianRenderer
from bayesian_fields_core.render.gsplat_median import accumulate_median, median_depth_from_meta
from bayesian_fields_core.render.output import RasterSettings
from bayesian_fields_core.render.projection import project
from bayesian_fields_core.render.tiles import bin_gaussians

from .scenes import make_gaussians, pinhole


def indices_in_range_cpu(
    range_start,
    range_end,
    transmittances,
    means2d,
    conics,
    opacities,
    width,
    height,
    tile_size,
    offsets,
    flatten,
):
    """Torch enumeration of gsplat's `rasterize_to_indices_in_range` for one camera."""
    xy, con, op = means2d[0], conics[0], opacities[0]
    trans_img = transmittances[0]
    tiles_y, tiles_x = offsets.shape[-2:]
    flat_off = torch.cat([offsets.flatten(), torch.tensor([flatten.numel()])])
    block = tile_size * tile_size
    gs_out, pix_out = [], []
    for tile in range(tiles_y * tiles_x):
        lst = flatten[flat_off[tile] : flat_off[tile + 1]]
        lo, hi = range_start * block, min(range_end * block, lst.numel())
        if lo >= hi:
            continue
        ids = lst[lo:hi]
        ty, tx = divmod(tile, tiles_x)
        rows = torch.arange(ty * tile_size, min((ty + 1) * tile_size, height))
        cols = torch.arange(tx * tile_size, min((tx + 1) * tile_size, width))
        pr, pc = torch.meshgrid(rows, cols, indexing="ij")
        pr, pc = pr.reshape(-1), pc.reshape(-1)
        dx = xy[ids, 0][None] - (pc[:, None] + 0.5)
        dy = xy[ids, 1][None] - (pr[:, None] + 0.5)
        c = con[ids]
        sigma = 0.5 * (c[None, :, 0] * dx * dx + c[None, :, 2] * dy * dy) + c[None, :, 1] * dx * dy
        alpha = (op[ids][None] * torch.exp(-sigma)).clamp_max(0.99)
        valid = (sigma >= 0) & (alpha >= 1.0 / 255.0)
        alpha = torch.where(valid, alpha, 0.0).double()
        t_after = trans_img[pr, pc].double()[:, None] * torch.cumprod(1.0 - alpha, dim=1)
        include = valid & (t_after > 1e-4)  # T only falls, so this is the traversal's prefix
        p_idx, g_idx = torch.nonzero(include, as_tuple=True)  # row-major: pixel, then depth order
        gs_out.append(ids[g_idx])
        pix_out.append(pr[p_idx] * width + pc[p_idx])
    gs = torch.cat(gs_out) if gs_out else torch.zeros(0, dtype=torch.long)
    pix = torch.cat(pix_out) if pix_out else torch.zeros(0, dtype=torch.long)
    return gs, pix, torch.zeros_like(pix)


def _meta(renderer: GaussianRenderer, K, w2c, width, height):
    s = renderer.settings
    K_t, w2c_t = torch.as_tensor(K), torch.as_tensor(w2c)
    proj = project(renderer.means, renderer.cov3d, renderer.opacities, K_t, w2c_t, width, height, s)
    tiles_x = (width + s.tile_size - 1) // s.tile_size
    tiles_y = (height + s.tile_size - 1) // s.tile_size
    bins = bin_gaussians(proj.rect, proj.depth, tiles_x, tiles_x * tiles_y)
    return {
        "means2d": proj.xy[None],
        "conics": proj.conic[None],
        "opacities": proj.opacity[None],
        "depths": proj.depth[None],
        "isect_offsets": bins.start.reshape(1, tiles_y, tiles_x),
        "flatten_ids": bins.entries,
        "tile_size": s.tile_size,
    }


def _scene(n=1500, seed=0):
    rng = np.random.default_rng(seed)
    means = np.c_[rng.uniform(-1.2, 1.2, n), rng.uniform(-0.9, 0.9, n), rng.uniform(2.0, 5.0, n)]
    scales = rng.uniform(0.03, 0.12, (n, 1)) * np.ones((1, 3))
    return make_gaussians(means, scales, opacities=rng.uniform(0.05, 0.6, n))


def test_median_from_gsplat_traversal_matches_torch_compositor():
    width, height = 48, 40
    settings = RasterSettings(tile_size=8)  # 64-entry batches: the median spans several of them
    renderer = GaussianRenderer(_scene(), backend="torch", settings=settings)
    K, w2c = pinhole(40.0, width, height), np.eye(4)
    _, _, reference, _ = renderer.render_tensors(K, w2c, width, height, depth_only=True)
    meta = _meta(renderer, K, w2c, width, height)
    assert (
        int(
            torch.diff(
                torch.cat([meta["isect_offsets"].flatten(), torch.tensor([meta["flatten_ids"].numel()])])
            ).max()
        )
        > 3 * 64
    )
    for per_call in (1, 3, 1000):
        median = median_depth_from_meta(
            meta,
            width,
            height,
            level=0.5,
            max_alpha=0.99,
            indices_fn=indices_in_range_cpu,
            batches_per_call=per_call,
        )
        assert median.shape == (height, width)
        assert (reference > 0).float().mean() > 0.5  # most pixels cross: a meaningful comparison
        same = torch.isclose(median, reference, atol=1e-5)
        assert same.float().mean() >= 0.995, per_call


def test_accumulate_median_orders_pairs_per_pixel_and_continues_transmittance():
    # Pixel 0: alphas 0.3, 0.4 (T 0.7 -> 0.42: crosses at the 2nd, depth 2.0).
    # Pixel 2: arrives at T 0.6, alpha 0.2 -> 0.48: crosses at its first pair here (depth 7.0).
    # Pixel 1 is interleaved to check that per-pixel grouping keeps each pixel's order.
    pix = torch.tensor([0, 1, 2, 0, 1])
    alpha = torch.tensor([0.3, 0.1, 0.2, 0.4, 0.1])
    depth = torch.tensor([1.0, 5.0, 7.0, 2.0, 6.0])
    trans = torch.tensor([1.0, 1.0, 0.6])
    median = torch.zeros(3)
    accumulate_median(pix, alpha, depth, trans, median, 0.5)
    assert torch.allclose(median, torch.tensor([2.0, 0.0, 7.0]))
    assert torch.allclose(trans, torch.tensor([0.42, 0.81, 0.48]))
