"""Depth ordering, expected/median depth, the 3DGS stopping rules and chunk invariance."""

from __future__ import annotations

import numpy as np

from bayesian_fields_core.render import GaussianRenderer, RasterSettings, render
from tests.core.render.scenes import make_gaussians, pinhole

W, H = 64, 48
K = pinhole(60.0, W, H)


def test_nearer_gaussian_wins_regardless_of_input_order() -> None:
    near = ([0.0, 0.0, 2.0], (1.0, 0.0, 0.0))
    far = ([0.02, 0.0, 4.0], (0.0, 1.0, 0.0))
    outs = []
    for order in ([far, near], [near, far]):
        g = make_gaussians([m for m, _ in order], 0.3, opacities=0.95, colours=[c for _, c in order])
        outs.append(render(g, K, np.eye(4), W, H))
    a, b = outs
    np.testing.assert_allclose(a.rgb, b.rgb, atol=1e-6)
    c = (H // 2, W // 2)
    # Centre pixel (centre 0.5 px right/below the principal point): red in front, green behind.
    a_near = 0.95 * np.exp(-0.5 * (0.25 + 0.25) / ((0.3 * 60 / 2) ** 2 + 0.3))
    dx_far = 0.5 - 0.02 * 60 / 4
    a_far = 0.95 * np.exp(-0.5 * (dx_far**2 + 0.25) / ((0.3 * 60 / 4) ** 2 + 0.3))
    w_near, w_far = a_near, (1 - a_near) * a_far
    np.testing.assert_allclose(a.rgb[c], [w_near, w_far, 0.0], atol=1e-5)
    assert abs(a.median_depth[c] - 2.0) < 1e-5
    expected_depth = (w_near * 2.0 + w_far * 4.0) / (w_near + w_far)
    assert abs(a.depth[c] - expected_depth) < 1e-4


def test_tilted_plane_gives_the_ray_intersection_depth() -> None:
    # Dense flat Gaussians on the plane z = 3 + 0.25 x, seen by a camera at the origin.
    xs, ys = np.meshgrid(np.arange(-2.0, 2.0, 0.02), np.arange(-1.5, 1.5, 0.02))
    x, y = xs.ravel(), ys.ravel()
    means = np.stack([x, y, 3.0 + 0.25 * x], axis=1)
    normal = np.array([-0.25, 0.0, 1.0]) / np.hypot(0.25, 1.0)
    # Rotate the thin axis (z) onto the plane normal: rotation about y by atan(-0.25).
    half = 0.5 * np.arctan2(-0.25, 1.0)
    quat = np.array([np.cos(half), 0.0, np.sin(half), 0.0])
    assert np.allclose(
        [2 * (quat[0] * quat[2]), 0.0, 1 - 2 * quat[2] ** 2], normal, atol=1e-9
    )  # R e_z = normal
    g = make_gaussians(means, (0.015, 0.015, 0.001), quats=np.tile(quat, (len(x), 1)), opacities=0.9)
    out = render(g, K, np.eye(4), W, H)

    cols, rows = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    ray_x = (cols - K[0, 2]) / K[0, 0]
    truth = 3.0 / (1.0 - 0.25 * ray_x)  # z of the ray (ray_x z, ray_y z, z) on the plane
    inner = (slice(8, H - 8), slice(8, W - 8))
    assert out.alpha[inner].min() > 0.99
    np.testing.assert_allclose(out.depth[inner], truth[inner], rtol=0.01)
    np.testing.assert_allclose(out.median_depth[inner], truth[inner], rtol=0.01)


def _reference_pixel(alphas: np.ndarray, colours: np.ndarray) -> tuple[np.ndarray, float]:
    """The 3DGS per-pixel loop, written out for a handful of sorted Gaussians."""
    rgb, t = np.zeros(3), 1.0
    for a, col in zip(alphas, colours, strict=True):
        a = min(0.99, a)
        if a < 1 / 255:
            continue
        if t * (1 - a) < 1e-4:
            break
        rgb += a * t * col
        t *= 1 - a
    return rgb, 1.0 - t


def test_transmittance_stop_and_alpha_skip_follow_3dgs() -> None:
    depths = np.array([1.0, 1.5, 2.0, 2.5, 3.0])
    colours = np.eye(3)[[0, 1, 2, 0, 1]] * np.array([[1.0], [1.0], [1.0], [0.5], [0.5]])
    opacities = np.array([0.95, 0.003, 0.95, 0.95, 0.95])  # the second one is below 1/255
    # Gaussians large enough to cover the centre pixel with alpha ~ opacity.
    means = np.stack([np.zeros(5), np.zeros(5), depths], axis=1)
    g = make_gaussians(means, depths[:, None] * 0.5, opacities=opacities, colours=colours)
    out = render(g, K, np.eye(4), W, H)
    c = (H // 2, W // 2)
    # Alpha of each Gaussian at the centre pixel: the pixel centre is 0.5 px off each mean.
    sigma_px = 0.5 * K[0, 0]
    alphas = opacities * np.exp(-0.5 * 0.5 / (sigma_px**2 + 0.3))
    rgb, alpha = _reference_pixel(alphas, colours)
    np.testing.assert_allclose(out.rgb[c], rgb, atol=1e-5)
    assert abs(out.alpha[c] - alpha) < 1e-5
    # Stop happened: the fourth Gaussian (T would drop to ~1.25e-4 * 0.05) is not included.
    assert 1.0 - out.alpha[c] >= 1e-4


def _random_scene(n: int, seed: int):
    rng = np.random.default_rng(seed)
    means = rng.uniform([-1.0, -0.8, 1.5], [1.0, 0.8, 4.0], size=(n, 3))
    quats = rng.normal(size=(n, 4))
    sh = rng.normal(scale=0.4, size=(n, 9, 3))
    return make_gaussians(
        means, rng.uniform(0.005, 0.08, size=(n, 3)), quats, rng.uniform(0.05, 0.99, n), sh=sh
    )


def test_chunk_and_batch_sizes_do_not_change_the_image() -> None:
    g = _random_scene(1000, seed=3)
    results = []
    for chunk, batch_elems in [(32, 1 << 22), (5, 256 * 5 * 4), (7, 256 * 7 * 5), (128, 1 << 16)]:
        settings = RasterSettings(chunk_size=chunk, max_batch_elements=batch_elems)
        results.append(render(g, K, np.eye(4), W, H, settings=settings))
    ref = results[0]
    assert ref.alpha.max() > 0.99 and ref.alpha.min() < 0.5  # a non-trivial image
    for other in results[1:]:
        for name in ("rgb", "depth", "median_depth", "alpha"):
            np.testing.assert_allclose(getattr(other, name), getattr(ref, name), atol=2e-5, err_msg=name)


def test_depth_only_matches_the_full_render() -> None:
    renderer = GaussianRenderer(_random_scene(800, seed=4), device="cpu", backend="torch")
    w2c = np.eye(4)
    w2c[:3, 3] = [0.1, 0.0, 0.3]
    full = renderer.render(K, w2c, W, H, background=(0.5, 0.5, 0.5))
    fast = renderer.render(K, w2c, W, H, depth_only=True)
    assert fast.rgb is None
    for name in ("depth", "median_depth", "alpha"):
        np.testing.assert_allclose(getattr(fast, name), getattr(full, name), atol=1e-6, err_msg=name)
    # The background shows through exactly where alpha is low.
    empty = full.alpha < 1e-6
    assert empty.any()
    np.testing.assert_allclose(full.rgb[empty], 0.5, atol=1e-5)


def test_skipping_the_median_leaves_features_and_transmittance_unchanged() -> None:
    import torch

    from bayesian_fields_core.render.composite import composite
    from bayesian_fields_core.render.projection import project
    from bayesian_fields_core.render.tiles import bin_gaussians

    rng = np.random.default_rng(5)
    means = np.stack([rng.uniform(-1, 1, 300), rng.uniform(-0.7, 0.7, 300), rng.uniform(2, 5, 300)], axis=1)
    g = make_gaussians(means, 0.05, opacities=0.8, colours=rng.uniform(0, 1, (300, 3)))
    r = GaussianRenderer(g, device="cpu", backend="torch")
    s = r.settings
    proj = project(r.means, r.cov3d, r.opacities, torch.tensor(K), torch.eye(4, dtype=torch.float64), W, H, s)
    tx, ty = (W + s.tile_size - 1) // s.tile_size, (H + s.tile_size - 1) // s.tile_size
    bins = bin_gaussians(proj.rect, proj.depth, tx, tx * ty)
    args = (proj.xy, proj.conic, proj.opacity, proj.depth, proj.depth[:, None], bins, tx, ty, s)
    full, lean = composite(*args), composite(*args, median=False)
    assert torch.equal(full.features, lean.features) and torch.equal(full.transmittance, lean.transmittance)
    assert full.median_depth.max() > 0 and not lean.median_depth.any()
