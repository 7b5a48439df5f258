"""Front-to-back alpha compositing of tile lists, vectorised over tiles, pixels and chunks.

Work proceeds in steps; each step takes a batch of still-active tiles and composites the next
`chunk_size` Gaussians of each tile's depth-ordered list for all the tile's pixels at once, as
(tiles, pixels, chunk) tensors. Transmittance within a chunk is a cumulative product, so the 3DGS
rules (skip alpha < min_alpha, stop before the Gaussian that drops transmittance below
stop_transmittance) hold exactly. Tiles leave the work queue when their list is exhausted or all
their pixels have stopped, so cost follows the visible depth complexity, and the step size caps
memory regardless of how many Gaussians the scene has.

The Gaussian exponent is a quadratic in the pixel offset from the tile centre, so it is evaluated
for a whole chunk as one batched matrix product (chunk x 6 coefficients) @ (6 x pixels).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from bayesian_fields_core.render.output import RasterSettings
from bayesian_fields_core.render.tiles import TileBins


@dataclass
class Composited:
    """Per-pixel results on the device, laid out as (tiles_y * tile, tiles_x * tile[, C])."""

    features: torch.Tensor  # alpha-weighted sums of the per-Gaussian features
    transmittance: torch.Tensor
    median_depth: torch.Tensor


def _pixel_basis(tile: int, device: torch.device) -> torch.Tensor:
    """(P, 6) monomials [p^2, q^2, pq, p, q, 1] of pixel-centre offsets from the tile centre."""
    r = torch.arange(tile, device=device, dtype=torch.float32) + 0.5 - tile / 2
    q, p = torch.meshgrid(r, r, indexing="ij")
    p, q = p.reshape(-1), q.reshape(-1)
    return torch.stack([p * p, q * q, p * q, p, q, torch.ones_like(p)], dim=-1)


def _exponent_coefficients(xy: torch.Tensor, conic: torch.Tensor, centre: torch.Tensor) -> torch.Tensor:
    """(..., 6) coefficients so that basis @ coef = -0.5 d^T Sigma2D^-1 d, d = pixel - mean."""
    u = xy[..., 0] - centre[..., 0]
    v = xy[..., 1] - centre[..., 1]
    a, b, c = conic.unbind(-1)
    return torch.stack(
        [
            -0.5 * a,
            -0.5 * c,
            -b,
            a * u + b * v,
            c * v + b * u,
            -(0.5 * a * u * u + 0.5 * c * v * v + b * u * v),
        ],
        dim=-1,
    )


def composite(
    xy: torch.Tensor,
    conic: torch.Tensor,
    opacity: torch.Tensor,
    depth: torch.Tensor,
    features: torch.Tensor,
    bins: TileBins,
    tiles_x: int,
    tiles_y: int,
    settings: RasterSettings,
) -> Composited:
    """Composite the binned Gaussians; `features` (M, F) are blended with the alpha weights."""
    device = xy.device
    tile = settings.tile_size
    n_pix = tile * tile
    n_tiles = tiles_x * tiles_y
    n_feat = features.shape[1]
    chunk = settings.chunk_size
    batch = max(1, settings.max_batch_elements // (n_pix * chunk))

    # Per-Gaussian table gathered by each step: x, y, conic a/b/c, opacity, depth, features.
    table = torch.cat([xy, conic, opacity[:, None], depth[:, None], features], dim=1).float()
    basis_t = _pixel_basis(tile, device)  # (P, 6)
    arange_chunk = torch.arange(chunk, device=device)
    tile_ids = torch.arange(n_tiles, device=device)
    centres = torch.stack([(tile_ids % tiles_x) * tile, (tile_ids // tiles_x) * tile], dim=-1)
    centres = (centres + tile / 2).float()

    acc = torch.zeros(n_tiles, n_pix, n_feat, device=device)
    trans = torch.ones(n_tiles, n_pix, device=device)
    done = torch.zeros(n_tiles, n_pix, dtype=torch.bool, device=device)
    median = torch.zeros(n_tiles, n_pix, device=device)
    progress = torch.zeros(n_tiles, dtype=torch.int64, device=device)
    # Longest lists first, so a batch holds tiles of similar length.
    active = torch.argsort(bins.count, descending=True)
    active = active[bins.count[active] > 0]
    last_entry = max(int(bins.entries.numel()) - 1, 0)

    while active.numel() > 0:
        cur, active = active[:batch], active[batch:]
        pos = bins.start[cur, None] + progress[cur, None] + arange_chunk  # (B, C)
        valid = (progress[cur, None] + arange_chunk) < bins.count[cur, None]
        rows = table[bins.entries[pos.clamp_max(last_entry)]]  # (B, C, 7 + F)
        coef = _exponent_coefficients(rows[..., 0:2], rows[..., 2:5], centres[cur, None, :])
        g_opacity = rows[..., 5] * valid
        g_depth = rows[..., 6]

        # alpha (B, P, C) = min(max_alpha, opacity * exp(exponent)), zeroed below min_alpha.
        alpha = torch.matmul(basis_t, coef.transpose(1, 2)).clamp_max_(0.0).exp_()
        alpha.mul_(g_opacity[:, None, :]).clamp_max_(settings.max_alpha)
        alpha.masked_fill_(alpha < settings.min_alpha, 0.0)

        t_prev = trans[cur]
        done_prev = done[cur]
        t_after = torch.cumprod(1.0 - alpha, dim=-1).mul_(t_prev[..., None])  # inclusive
        include = (t_after >= settings.stop_transmittance) & ~done_prev[..., None]
        t_before = t_after / (1.0 - alpha)
        weight = alpha.mul_(t_before).mul_(include)
        acc[cur] += torch.matmul(weight, rows[..., 7:])

        crossing = (
            include & (t_after < settings.median_transmittance) & (t_before >= settings.median_transmittance)
        )
        median[cur] += torch.matmul(crossing.float(), g_depth[..., None]).squeeze(-1)
        trans[cur] = torch.where(include, t_after, t_prev[..., None]).amin(dim=-1)
        now_done = done_prev | (t_after[..., -1] < settings.stop_transmittance)
        done[cur] = now_done

        progress[cur] += chunk
        more = (progress[cur] < bins.count[cur]) & ~now_done.all(dim=-1)
        active = torch.cat([active, cur[more]])

    def to_image(x: torch.Tensor) -> torch.Tensor:
        x = x.reshape(tiles_y, tiles_x, tile, tile, *x.shape[2:])
        return x.transpose(1, 2).reshape(tiles_y * tile, tiles_x * tile, *x.shape[4:])

    return Composited(features=to_image(acc), transmittance=to_image(trans), median_depth=to_image(median))
