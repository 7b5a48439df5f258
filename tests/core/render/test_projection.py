"""A single Gaussian must land as the analytic EWA ellipse at the projected mean."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from bayesian_fields_core.render import render
from tests.core.render.scenes import make_gaussians

W, H = 96, 80
K = np.array([[120.0, 0.0, 45.0], [0.0, 110.0, 38.0], [0.0, 0.0, 1.0]])


def _camera() -> np.ndarray:
    """A rotated, translated camera, so the test exercises the world-to-camera rotation."""
    w2c = np.eye(4)
    w2c[:3, :3] = Rotation.from_euler("xyz", [0.2, -0.3, 0.1]).as_matrix()
    w2c[:3, 3] = [0.1, -0.2, 0.5]
    return w2c


def _expected_alpha(mean, scales, quat_wxyz, opacity, w2c) -> tuple[np.ndarray, np.ndarray]:
    """Alpha image and projected centre from the EWA formulas, computed independently here."""
    rot = Rotation.from_quat([*quat_wxyz[1:], quat_wxyz[0]]).as_matrix()  # scipy wants xyzw
    cov3 = rot @ np.diag(np.square(scales)) @ rot.T
    x, y, z = w2c[:3, :3] @ mean + w2c[:3, 3]
    fx, fy = K[0, 0], K[1, 1]
    jac = np.array([[fx / z, 0, -fx * x / z**2], [0, fy / z, -fy * y / z**2]])
    cov2 = jac @ w2c[:3, :3] @ cov3 @ w2c[:3, :3].T @ jac.T + 0.3 * np.eye(2)
    centre = np.array([fx * x / z + K[0, 2], fy * y / z + K[1, 2]])
    cols, rows = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    d = np.stack([cols - centre[0], rows - centre[1]], axis=-1)
    maha = np.einsum("hwi,ij,hwj->hw", d, np.linalg.inv(cov2), d)
    alpha = np.minimum(0.99, opacity * np.exp(-0.5 * maha))
    return alpha, centre


def test_single_gaussian_is_the_analytic_ellipse() -> None:
    mean = np.array([0.05, 0.1, 2.5])
    scales = np.array([0.08, 0.03, 0.01])
    quat = np.array([0.8, 0.3, -0.4, 0.2])
    quat = quat / np.linalg.norm(quat)
    opacity = 0.8
    w2c = _camera()
    g = make_gaussians(mean, scales, quat, opacity, colours=(1.0, 0.25, 0.0))
    out = render(g, K, w2c, W, H)
    expected, centre = _expected_alpha(mean, scales, quat, opacity, w2c)

    # Brightest pixel = the pixel containing the projected mean (pixel centres at +0.5).
    row, col = np.unravel_index(np.argmax(out.alpha), out.alpha.shape)
    assert (col, row) == (int(centre[0]), int(centre[1]))
    # Alpha at a few offsets, along and across the ellipse, matches the analytic Gaussian.
    for dr, dc in [(0, 0), (0, 3), (2, 0), (-3, 4), (4, -2), (-1, -6)]:
        r, c = row + dr, col + dc
        if expected[r, c] >= 1 / 255:
            np.testing.assert_allclose(out.alpha[r, c], expected[r, c], rtol=1e-3, atol=1e-6)
    # Everywhere the alpha passes the 1/255 cut inside the 3-sigma footprint, it matches.
    significant = expected > 0.02
    assert significant.sum() > 20
    np.testing.assert_allclose(out.alpha[significant], expected[significant], rtol=1e-3)
    # Colour is alpha * (1, 0.25, 0) over a black background; depth is the camera z.
    np.testing.assert_allclose(out.rgb[row, col], out.alpha[row, col] * np.array([1.0, 0.25, 0.0]), atol=1e-5)
    z = (w2c[:3, :3] @ mean + w2c[:3, 3])[2]
    assert abs(out.depth[row, col] - z) < 1e-4
    assert abs(out.median_depth[row, col] - z) < 1e-4  # alpha 0.8 crosses T = 0.5
    assert out.depth[out.alpha < 1e-3].max() == 0.0


def test_near_plane_and_off_screen_gaussians_are_culled() -> None:
    g = make_gaussians(
        [[0.0, 0.0, 0.005], [0.0, 0.0, -2.0], [30.0, 0.0, 2.0]],  # too near, behind, off-screen
        0.05,
        opacities=0.9,
    )
    out = render(g, K, np.eye(4), W, H, background=(0.2, 0.4, 0.6))
    assert out.alpha.max() == 0.0
    np.testing.assert_allclose(out.rgb, np.broadcast_to([0.2, 0.4, 0.6], (H, W, 3)), atol=1e-7)
    assert out.depth.max() == 0.0 and out.median_depth.max() == 0.0


def test_empty_splat_renders_background() -> None:
    g = make_gaussians(np.zeros((0, 3)), 0.1)
    out = render(g, K, np.eye(4), W, H, background=(1.0, 1.0, 1.0))
    assert out.rgb.shape == (H, W, 3) and np.all(out.rgb == 1.0)
    assert out.alpha.shape == (H, W) and out.alpha.max() == 0.0
