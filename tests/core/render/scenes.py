"""Scene builders shared by the renderer tests."""

from __future__ import annotations

import numpy as np

from bayesian_fields_core.geometry.spherical_harmonics import C0
from bayesian_fields_core.scene.types import Gaussians


def make_gaussians(
    means,
    scales,
    quats=None,
    opacities=None,
    colours=None,
    sh: np.ndarray | None = None,
) -> Gaussians:
    """Gaussians from natural parameters: scales (std devs), opacities in (0,1), RGB colours."""
    means = np.asarray(means, dtype=np.float32).reshape(-1, 3)
    n = len(means)
    scales = np.broadcast_to(np.asarray(scales, dtype=np.float32), (n, 3))
    quats = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1)) if quats is None else quats
    opacities = np.full(n, 0.9) if opacities is None else np.broadcast_to(opacities, (n,))
    if sh is None:
        colours = np.full((n, 3), 0.5) if colours is None else np.broadcast_to(colours, (n, 3))
        sh = ((np.asarray(colours) - 0.5) / C0)[:, None, :]
    return Gaussians(
        means=means,
        log_scales=np.log(scales).astype(np.float32),
        quats=np.asarray(quats, dtype=np.float32).reshape(n, 4),
        opacity_logits=np.log(opacities / (1.0 - opacities)).astype(np.float32),
        sh=np.asarray(sh, dtype=np.float32),
    )


def pinhole(f: float, width: int, height: int) -> np.ndarray:
    return np.array([[f, 0.0, width / 2], [0.0, f, height / 2], [0.0, 0.0, 1.0]])
