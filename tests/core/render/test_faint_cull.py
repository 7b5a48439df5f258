"""The faint-tile cull of binning: its box minimum is the true one, it drops tile entries of
elongated footprints, and the rendered image is the same as without it."""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from bayesian_fields_core.render import GaussianRenderer, RasterSettings
from bayesian_fields_core.render.projection import project
from bayesian_fields_core.render.tiles import _min_quadratic_on_box, bin_gaussians, faint_cull
from tests.core.render.scenes import make_gaussians, pinhole

W, H = 96, 64
K = pinhole(70.0, W, H)


def test_box_minimum_matches_a_dense_grid() -> None:
    rng = np.random.default_rng(3)
    n = 200
    lo = rng.uniform(-6, 4, size=(n, 2))
    hi = lo + rng.uniform(0.5, 5, size=(n, 2))
    m = rng.normal(size=(n, 2, 2))
    cov = m @ m.transpose(0, 2, 1) + 0.1 * np.eye(2)
    inv = np.linalg.inv(cov)
    conic = np.stack([inv[:, 0, 0], inv[:, 0, 1], inv[:, 1, 1]], axis=1)
    got = _min_quadratic_on_box(*(torch.tensor(x, dtype=torch.float64) for x in
                                  (lo[:, 0], hi[:, 0], lo[:, 1], hi[:, 1], conic))).numpy()  # fmt: skip
    s = np.linspace(0, 1, 201)
    for i in range(n):
        x = lo[i, 0] + s[:, None] * (hi[i, 0] - lo[i, 0])
        y = lo[i, 1] + s[None, :] * (hi[i, 1] - lo[i, 1])
        a, b, c = conic[i]
        grid = (a * x * x + 2 * b * x * y + c * y * y).min()
        assert got[i] <= grid + 1e-9  # never above the true minimum (the cull stays conservative)
        assert got[i] >= grid - 1e-3 * max(1.0, grid)  # and the grid approaches it


def _elongated_scene():
    rng = np.random.default_rng(0)
    n = 400
    means = np.stack([rng.uniform(-1.2, 1.2, n), rng.uniform(-0.8, 0.8, n), rng.uniform(2.0, 4.0, n)], axis=1)
    quats = rng.normal(size=(n, 4))
    scales = np.stack([rng.uniform(0.08, 0.2, n), np.full(n, 0.004), np.full(n, 0.004)], axis=1)
    colours = rng.uniform(0, 1, size=(n, 3))
    return make_gaussians(means, scales, quats=quats, opacities=rng.uniform(0.05, 0.95, n), colours=colours)


def test_cull_drops_entries_but_not_pixels() -> None:
    g = _elongated_scene()
    base = RasterSettings(tile_size=8)
    culled = dataclasses.replace(base, cull_faint_tiles=True)
    r = GaussianRenderer(g, device="cpu", backend="torch", settings=base)
    proj = project(
        r.means, r.cov3d, r.opacities, torch.tensor(K), torch.eye(4, dtype=torch.float64), W, H, base
    )
    tiles_x, tiles_y = (W + 7) // 8, (H + 7) // 8
    full = bin_gaussians(proj.rect, proj.depth, tiles_x, tiles_x * tiles_y)
    kept = bin_gaussians(proj.rect, proj.depth, tiles_x, tiles_x * tiles_y, faint_cull(proj, culled))
    assert faint_cull(proj, base) is None
    assert kept.entries.numel() < 0.8 * full.entries.numel()

    a = r.render(K, np.eye(4), W, H)
    b = GaussianRenderer(g, device="cpu", backend="torch", settings=culled).render(K, np.eye(4), W, H)
    assert a.alpha.max() > 0.5
    for x, y in ((a.rgb, b.rgb), (a.alpha, b.alpha), (a.depth, b.depth), (a.median_depth, b.median_depth)):
        np.testing.assert_allclose(x, y, atol=1e-5)
