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

import numpy as np
import torch

from bayesian_fields_core.render.output import RasterSettings
from bayesian_fields_core.render.tiles import TileBins


@dataclass
class Composited:
    """Per-pixel results on the device, laid out as (tiles_y * tile, tiles_x * tile[, C])."""

    features: torch.Tensor  # alpha-weighted sums of the per-Gaussian features
    transmittance: torch.Tensor
    median_depth: torch.Tensor


# exp(-30) ~ 1e-13: far below any min_alpha, far above the float32 denormal range.
_EXPONENT_FLOOR = -30.0


def _pixel_basis(tile: int, device: torch.device) -> torch.Tensor:
    """(P, 6) monomials [p^2, q^2, pq, p, q, 1] of pixel-centre offsets from the tile centre."""
    r = torch.arange(tile, device=device, dtype=torch.float32) + 0.5 - tile / 2
    q, p = torch.meshgrid(r, r, indexing="ij")
    p, q = p.reshape(-1), q.reshape(-1)
    return torch.stack([p * p, q * q, p * q, p, q, torch.ones_like(p)], dim=-1)


def _exponent_coefficients(
    xy: torch.Tensor, conic: torch.Tensor, centre: torch.Tensor, constant: torch.Tensor
) -> torch.Tensor:
    """(..., 6) coefficients so that basis @ coef = -0.5 d^T Sigma2D^-1 d + constant, d = pixel - mean."""
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
            constant - (0.5 * a * u * u + 0.5 * c * v * v + b * u * v),
        ],
        dim=-1,
    )


def _levels(neg_t: torch.Tensor, level: float) -> torch.Tensor:
    """(..., 1) search values -level for counting the entries of T = -neg_t that are >= level."""
    return torch.full((*neg_t.shape[:-1], 1), -level, device=neg_t.device, dtype=neg_t.dtype)


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
    *,
    median: bool = True,
) -> Composited:
    """Composite the binned Gaussians; `features` (M, F) are blended with the alpha weights.

    `median=False` skips the median-depth search (two ops per step) for callers that only need
    the blended features and transmittance, such as previews; `median_depth` is then all zero.
    Features and transmittance are the same either way."""
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
    median_depth = torch.zeros(n_tiles, n_pix, device=device)
    progress = torch.zeros(n_tiles, dtype=torch.int64, device=device)
    # Longest lists first, so a batch holds tiles of similar length.
    active = torch.argsort(bins.count, descending=True)
    active = active[bins.count[active] > 0]
    last_entry = max(int(bins.entries.numel()) - 1, 0)

    # F.threshold keeps x > t; this t makes it keep exactly alpha >= min_alpha (float32).
    below_min_alpha = float(np.nextafter(np.float32(settings.min_alpha), np.float32(0.0)))
    log_floor = float(np.log(settings.stop_transmittance) - 1.0)
    # Work buffers reused by every step: fresh multi-MB tensors per op would cost page faults.
    batch = min(batch, max(int(active.numel()), 1))
    buf_a, buf_t, buf_n = (torch.empty(batch, n_pix, chunk, device=device) for _ in range(3))
    buf_mask = torch.empty(batch, n_pix, chunk, dtype=torch.bool, device=device)

    while active.numel() > 0:
        cur, active = active[:batch], active[batch:]
        b = cur.numel()
        offset = progress[cur, None] + arange_chunk  # (b, C) position in each tile's list
        valid = offset < bins.count[cur, None]
        rows = table[bins.entries[(bins.start[cur, None] + offset).clamp_max(last_entry)]]
        # log(opacity) joins the constant term, so log(alpha) = basis @ coef in one product;
        # padding entries get a huge negative constant, i.e. alpha = 0.
        log_opacity = torch.where(valid, rows[..., 5].log(), -1e4)
        coef = _exponent_coefficients(rows[..., 0:2], rows[..., 2:5], centres[cur, None, :], log_opacity)

        # alpha (b, P, C) = min(max_alpha, opacity * exp(-0.5 d^T conic d)), 0 below min_alpha.
        # The exponent is floored first: far tails would otherwise become float32 denormals,
        # and exp() of huge negatives leaves the vectorised fast path; both are slow on CPUs.
        alpha = torch.matmul(basis_t, coef.transpose(1, 2), out=buf_a[:b])
        alpha.clamp_min_(_EXPONENT_FLOOR).exp_().clamp_max_(settings.max_alpha)
        torch.threshold_(alpha, below_min_alpha, 0.0)  # = torch.nn.functional.threshold_ (stubs lack it)

        t_prev = trans[cur]
        done_prev = done[cur]
        # Stopped pixels start from zero transmittance, so nothing further is included.
        t_start = t_prev.masked_fill(done_prev, 0.0)[..., None]
        # Inclusive transmittance, accumulated in log space and floored just below the stop
        # level: a plain cumprod of many (1 - 0.99) factors underflows into float32 denormals,
        # which are slow on CPUs. Floored entries are below the stop level, so are excluded.
        t_after = torch.sub(1.0, alpha, out=buf_t[:b]).log_().cumsum_(dim=-1).add_(t_start.log())
        t_after.clamp_min_(log_floor).exp_()
        # T is non-increasing along the chunk, so the included Gaussians (T_after >= stop) are a
        # prefix; its length comes from a binary search on -T (a bool .sum() would cast to int64).
        neg_t = torch.neg(t_after, out=buf_n[:b])
        n_include = torch.searchsorted(neg_t, _levels(neg_t, settings.stop_transmittance), right=True)[..., 0]
        # weight = T_before - T_after = alpha * T_before for the included Gaussians, else 0.
        weight = buf_a[:b]  # alpha is no longer needed
        weight[..., :1] = t_start
        weight[..., 1:] = t_after[..., :-1]
        excluded = torch.lt(t_after, settings.stop_transmittance, out=buf_mask[:b])
        weight.sub_(t_after).masked_fill_(excluded, 0.0)
        acc[cur] += torch.matmul(weight, rows[..., 7:])

        if median:
            # The first Gaussian whose inclusion drops T below the level, if in this chunk.
            k = torch.searchsorted(neg_t, _levels(neg_t, settings.median_transmittance), right=True)[..., 0]
            crossed = (t_start[..., 0] >= settings.median_transmittance) & (k < n_include)
            k_depth = rows[..., 6].gather(1, k.clamp_max(chunk - 1))
            median_depth[cur] += torch.where(crossed, k_depth, 0.0)

        last = t_after.gather(-1, (n_include - 1).clamp_min(0)[..., None])[..., 0]
        trans[cur] = torch.where(n_include > 0, last, t_prev)
        now_done = done_prev | (n_include < chunk)
        done[cur] = now_done

        progress[cur] += chunk
        more = (progress[cur] < bins.count[cur]) & ~now_done.all(dim=-1)
        active = torch.cat([active, cur[more]])

    def to_image(x: torch.Tensor) -> torch.Tensor:
        x = x.reshape(tiles_y, tiles_x, tile, tile, *x.shape[2:])
        return x.transpose(1, 2).reshape(tiles_y * tile, tiles_x * tile, *x.shape[4:])

    return Composited(
        features=to_image(acc), transmittance=to_image(trans), median_depth=to_image(median_depth)
    )
