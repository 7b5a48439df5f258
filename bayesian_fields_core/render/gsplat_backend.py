"""Adapter to gsplat's CUDA rasteriser (optional extra `bayesian-fields[gpu]`).

gsplat is imported lazily and only when asked for, so the library works without it. It renders
colour, expected depth and alpha; it has no median-depth mode for 3D Gaussians, so the median
comes from gsplat's own traversal (`rasterize_to_indices_in_range`) over the projection this
call returns in its `meta` (see `gsplat_median`); no torch rasteriser runs beside it.
Written against gsplat 1.x's `rasterization(means, quats, scales, opacities, colors, viewmats,
Ks, width, height, near_plane=, eps2d=, sh_degree=, packed=, tile_size=, render_mode=)`,
render modes "ED" (expected depth) and "RGB+ED".
"""

from __future__ import annotations

import importlib.util
from typing import Any

import torch

from bayesian_fields_core.render.gsplat_median import median_depth_from_meta


def gsplat_available() -> bool:
    """True when gsplat can be imported and CUDA is usable (gsplat's kernels need both)."""
    return importlib.util.find_spec("gsplat") is not None and torch.cuda.is_available()


def rasterize_gsplat(
    means: torch.Tensor,
    quats: torch.Tensor,
    scales: torch.Tensor,
    opacities: torch.Tensor,
    sh: torch.Tensor,
    K: torch.Tensor,
    world_to_camera: torch.Tensor,
    width: int,
    height: int,
    *,
    near_plane: float,
    eps2d: float,
    tile_size: int,
    depth_only: bool,
) -> tuple[torch.Tensor | None, torch.Tensor, torch.Tensor, dict[str, Any]]:
    """Render with `gsplat.rasterization`: (rgb (H,W,3) | None, depth (H,W), alpha (H,W), meta).

    rgb is not composited over a background and depth is gsplat's alpha-normalised expected
    depth; the caller applies the background and the min-alpha depth cut-off. `packed=False`
    keeps meta's projection dense per camera ((1, N, ...)), the layout the index kernel reads.
    """
    from gsplat import rasterization  # noqa: PLC0415 - optional dependency, imported on use

    viewmats = world_to_camera.float()[None]
    Ks = K.float()[None]
    if depth_only:
        colors = torch.zeros(means.shape[0], 3, device=means.device)
        sh_degree = None
        mode = "ED"
    else:
        colors = sh
        sh_degree = int(round(sh.shape[1] ** 0.5)) - 1
        mode = "RGB+ED"
    render_colors, render_alphas, meta = rasterization(
        means=means,
        quats=quats,
        scales=scales,
        opacities=opacities,
        colors=colors,
        viewmats=viewmats,
        Ks=Ks,
        width=width,
        height=height,
        near_plane=near_plane,
        eps2d=eps2d,
        sh_degree=sh_degree,
        tile_size=tile_size,
        render_mode=mode,
        packed=False,
    )
    out = render_colors[0]
    alpha = render_alphas[0, ..., 0]
    rgb = None if depth_only else out[..., :3]
    return rgb, out[..., -1], alpha, meta


def median_depth_gsplat(
    meta: dict[str, Any], width: int, height: int, *, level: float, max_alpha: float
) -> torch.Tensor:
    """(H, W) median depth from gsplat's traversal of the projection in `meta` (CUDA only)."""
    from gsplat import rasterize_to_indices_in_range  # noqa: PLC0415 - optional dependency

    return median_depth_from_meta(
        meta, width, height, level=level, max_alpha=max_alpha, indices_fn=rasterize_to_indices_in_range
    )
