"""Binning screen-space Gaussians into tiles, each tile's list in front-to-back order.

Like the CUDA rasteriser: every Gaussian is duplicated once per tile its footprint box touches,
and the duplicates are ordered by (tile, depth). Here the Gaussians are first ordered by depth and
the duplicates then stably sorted by tile, which gives the same order with a narrower sort key.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from bayesian_fields_core.render.output import RasterSettings
from bayesian_fields_core.render.projection import Projected


@dataclass
class TileBins:
    """Per-tile Gaussian lists, concatenated.

    entries: (L,) indices into the Projected arrays, grouped by tile, nearest first in a tile.
    start, count: (n_tiles,) int64 offset of each tile's list in `entries`, and its length.
    """

    entries: torch.Tensor
    start: torch.Tensor
    count: torch.Tensor


@dataclass
class FaintCull:
    """What `bin_gaussians` needs to drop a duplicate whose alpha is below `min_alpha` at every
    pixel centre of its tile: xy (M, 2) means, conic (M, 3) as (a, b, c), opacity (M,)."""

    xy: torch.Tensor
    conic: torch.Tensor
    opacity: torch.Tensor
    min_alpha: float
    tile_size: int


def faint_cull(proj: Projected, settings: RasterSettings) -> FaintCull | None:
    """The `bin_gaussians` cull of `proj` when `settings.cull_faint_tiles` asks for it, else None."""
    if not settings.cull_faint_tiles:
        return None
    return FaintCull(proj.xy, proj.conic, proj.opacity, settings.min_alpha, settings.tile_size)


# Duplicates are dropped only when their best log-alpha is this far below log(min_alpha), so
# float32 rounding at the threshold never drops one the compositing would have kept.
_CULL_MARGIN = 1e-3


def _min_quadratic_on_box(
    lo_x: torch.Tensor, hi_x: torch.Tensor, lo_y: torch.Tensor, hi_y: torch.Tensor, conic: torch.Tensor
) -> torch.Tensor:
    """(L,) minimum of a dx^2 + 2 b dx dy + c dy^2 over the boxes [lo_x, hi_x] x [lo_y, hi_y].

    The form is positive definite, so the minimum is 0 when the box holds the origin and else lies
    on an edge; on an edge it is a 1D quadratic, minimised by clamping its vertex to the edge."""
    a, b, c = conic.unbind(-1)
    best = torch.full_like(a, math.inf)
    for x in (lo_x, hi_x):  # vertical edges: dx fixed
        y = (-b * x / c).clamp(lo_y, hi_y)
        best = torch.minimum(best, a * x * x + 2 * b * x * y + c * y * y)
    for y in (lo_y, hi_y):  # horizontal edges: dy fixed
        x = (-b * y / a).clamp(lo_x, hi_x)
        best = torch.minimum(best, a * x * x + 2 * b * x * y + c * y * y)
    inside = (lo_x <= 0) & (hi_x >= 0) & (lo_y <= 0) & (hi_y >= 0)
    return best.masked_fill(inside, 0.0)


def _faint(owner_ids: torch.Tensor, tile: torch.Tensor, tiles_x: int, cull: FaintCull) -> torch.Tensor:
    """(L,) bool: duplicates (Gaussian owner_ids[i] in tile[i]) with alpha < min_alpha at every
    pixel centre of the tile, so compositing would skip them anyway."""
    t = cull.tile_size
    u, v = cull.xy[owner_ids].unbind(-1)
    tx = (tile % tiles_x).float() * t + 0.5  # first pixel centre of the tile
    ty = torch.div(tile, tiles_x, rounding_mode="floor").float() * t + 0.5
    q = _min_quadratic_on_box(tx - u, tx + (t - 1) - u, ty - v, ty + (t - 1) - v, cull.conic[owner_ids])
    best_log_alpha = cull.opacity[owner_ids].log() - 0.5 * q
    return best_log_alpha < math.log(cull.min_alpha) - _CULL_MARGIN


def bin_gaussians(
    rect: torch.Tensor, depth: torch.Tensor, tiles_x: int, n_tiles: int, cull: FaintCull | None = None
) -> TileBins:
    """Build the (tile, depth)-ordered duplicate lists from inclusive tile rects (M, 4).

    With `cull`, duplicates whose Gaussian is fainter than min_alpha on the whole tile are left
    out (the rect is a square around the 3-sigma ellipse, so for elongated footprints many of its
    tiles are such): the compositing result is the same up to float rounding, at less work."""
    device = rect.device
    order = torch.argsort(depth, stable=True)
    x0, y0, x1, y1 = rect[order].unbind(-1)
    span_x = x1 - x0 + 1
    n_dup = span_x * (y1 - y0 + 1)
    owner = torch.repeat_interleave(torch.arange(order.numel(), device=device), n_dup)
    first = torch.cumsum(n_dup, 0) - n_dup
    k = torch.arange(owner.numel(), device=device) - first[owner]
    span_owner = span_x[owner]
    tile = (y0[owner] + torch.div(k, span_owner, rounding_mode="floor")) * tiles_x + (
        x0[owner] + k % span_owner
    )
    del k, span_owner, first
    if cull is not None:
        keep = ~_faint(order[owner], tile, tiles_x, cull)
        owner, tile = owner[keep], tile[keep]
    tile_sorted, perm = torch.sort(tile.int(), stable=True)
    del tile
    entries = order[owner[perm]]
    count = torch.bincount(tile_sorted, minlength=n_tiles)
    start = torch.cumsum(count, 0) - count
    return TileBins(entries=entries, start=start, count=count)
