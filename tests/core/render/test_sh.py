"""View-dependent colour: SH basis constants and per-view evaluation in the rendered image."""

from __future__ import annotations

import numpy as np
import torch

from bayesian_fields_core.geometry.spherical_harmonics import C0, C1, sh_basis
from bayesian_fields_core.render import render
from tests.core.render.scenes import make_gaussians, pinhole


def test_sh_basis_is_orthonormal_on_the_sphere() -> None:
    # Fibonacci sphere quadrature: (4 pi / n) sum Y_i Y_j -> identity for a real orthonormal basis.
    n = 20000
    k = np.arange(n) + 0.5
    z = 1 - 2 * k / n
    phi = np.pi * (1 + 5**0.5) * k
    r = np.sqrt(1 - z * z)
    dirs = torch.tensor(np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1))
    basis = sh_basis(dirs, 3).numpy()
    gram = 4 * np.pi / n * basis.T @ basis
    np.testing.assert_allclose(gram, np.eye(16), atol=2e-3)


def test_degree_one_colour_follows_the_view_direction() -> None:
    W, H = 32, 32
    K = pinhole(40.0, W, H)
    mean = np.array([0.3, -0.2, 0.0])
    sh = np.zeros((1, 4, 3))
    sh[0, 0] = [0.2, 0.0, -0.1]
    sh[0, 1] = [0.3, -0.2, 0.0]  # multiplies -C1 * y
    sh[0, 2] = [0.0, 0.4, 0.1]  # multiplies  C1 * z
    sh[0, 3] = [-0.5, 0.1, 0.2]  # multiplies -C1 * x
    g = make_gaussians(mean, 0.2, opacities=0.9, sh=sh)

    colours = []
    for centre in ([0.3, -0.2, -3.0], [2.0, 1.0, -2.5], [-1.5, -1.8, -2.0]):
        centre = np.asarray(centre)
        forward = (mean - centre) / np.linalg.norm(mean - centre)  # look at the Gaussian
        right = np.cross([0.0, 1.0, 0.0], forward)
        right /= np.linalg.norm(right)
        down = np.cross(forward, right)
        rot = np.stack([right, down, forward])  # rows: camera axes in world coordinates
        w2c = np.eye(4)
        w2c[:3, :3] = rot
        w2c[:3, 3] = -rot @ centre
        out = render(g, K, w2c, W, H)
        r, c = np.unravel_index(np.argmax(out.alpha), out.alpha.shape)
        x, y, z = forward
        expected = C0 * sh[0, 0] - C1 * y * sh[0, 1] + C1 * z * sh[0, 2] - C1 * x * sh[0, 3] + 0.5
        expected = np.maximum(expected, 0.0)
        np.testing.assert_allclose(out.rgb[r, c] / out.alpha[r, c], expected, atol=1e-4)
        colours.append(expected)
    assert np.ptp(np.array(colours), axis=0).max() > 0.1  # the views really differ in colour
