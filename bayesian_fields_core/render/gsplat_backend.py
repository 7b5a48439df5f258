"""Adapter to gsplat's CUDA rasteriser (optional extra `bayesian-fields[gpu]`).

gsplat is imported lazily and only when asked for, so the library works without it. It renders
colour, expected depth and alpha; it has no median-depth output, so the renderer fills that in
with its own torch compositor (depth-only, on the same GPU).
"""

from __future__ import annotations

import importlib.util

import torch


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
) -> tuple[torch.Tensor | None, torch.Tensor, torch.Tensor]:
    """Render with `gsplat.rasterization`; returns (rgb (H,W,3) | None, depth (H,W), alpha (H,W)).

    rgb is not composited over a background and depth is gsplat's alpha-normalised expected
    depth; the caller applies the background and the min-alpha depth cut-off.
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
    render_colors, render_alphas, _meta = rasterization(
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
    )
    out = render_colors[0]
    alpha = render_alphas[0, ..., 0]
    rgb = None if depth_only else out[..., :3]
    return rgb, out[..., -1], alpha
