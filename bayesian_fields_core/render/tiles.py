"""Binning screen-space Gaussians into tiles, each tile's list in front-to-back order.

Like the CUDA rasteriser: every Gaussian is duplicated once per tile its footprint box touches,
and the duplicates are ordered by (tile, depth). Here the Gaussians are first ordered by depth and
the duplicates then stably sorted by tile, which gives the same order with a narrower sort key.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch


@dataclass
class TileBins:
    """Per-tile Gaussian lists, concatenated.

    entries: (L,) indices into the Projected arrays, grouped by tile, nearest first in a tile.
    start, count: (n_tiles,) int64 offset of each tile's list in `entries`, and its length.
    """

    entries: torch.Tensor
    start: torch.Tensor
    count: torch.Tensor


def bin_gaussians(rect: torch.Tensor, depth: torch.Tensor, tiles_x: int, n_tiles: int) -> TileBins:
    """Build the (tile, depth)-ordered duplicate lists from inclusive tile rects (M, 4)."""
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
    tile_sorted, perm = torch.sort(tile.int(), stable=True)
    del tile
    entries = order[owner[perm]]
    count = torch.bincount(tile_sorted, minlength=n_tiles)
    start = torch.cumsum(count, 0) - count
    return TileBins(entries=entries, start=start, count=count)
