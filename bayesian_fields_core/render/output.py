"""The renderer's result and its tuning knobs, shared by every backend.

Kept apart from the rasteriser so callers (fusion, the CLI, tests) can import the types without
pulling in torch-heavy code paths, and so the torch and gsplat backends agree on one contract.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class RenderOutput:
    """One rendered view; every array is (H, W[, 3]) float32 numpy.

    rgb: colour in [0, 1] composited over the background; None for a depth-only render.
    depth: expected camera-space depth (sum of w_i z_i / alpha), 0 where alpha < 1e-3.
    median_depth: depth of the Gaussian at which the accumulated transmittance first drops
        below 0.5; 0 where it never does.
    alpha: accumulated opacity, 1 - final transmittance.
    """

    rgb: np.ndarray | None
    depth: np.ndarray
    median_depth: np.ndarray
    alpha: np.ndarray


@dataclass(frozen=True)
class RasterSettings:
    """Rasterisation constants. The defaults are those of the reference 3DGS rasteriser.

    near_plane: Gaussians whose centre is nearer than this (scene units, camera z) are culled; the
        pipeline replaces it by a fraction of the scene scale (`GaussianRenderer(near_plane=)`).
    eps2d: low-pass dilation added to the diagonal of every 2D covariance (pixels^2), so a
        Gaussian never shrinks below about a pixel and cannot alias.
    fov_clamp: the camera-space x/z and y/z used in the projection Jacobian are clamped to this
        multiple of the image half-extent (tan of the half FOV), which keeps Gaussians far
        outside the frustum from exploding into huge screen-space ellipses.
    sigma_extent: screen-space radius, in standard deviations, of the footprint used for
        culling and for binning into tiles.
    min_alpha: per-Gaussian alphas below this are skipped (they cannot change an 8-bit pixel).
    max_alpha: alphas are clamped to this, so one Gaussian never makes a pixel fully opaque.
    stop_transmittance: a pixel stops compositing before the Gaussian that would drop its
        transmittance below this.
    median_transmittance: the transmittance level whose crossing defines the median depth.
    min_depth_alpha: pixels with less accumulated alpha than this get depth 0 (no surface).
    tile_size: side of the square screen tiles Gaussians are binned into (pixels).
    chunk_size: how many depth-ordered Gaussians of a tile are composited per step; smaller
        wastes less work past early termination, larger means fewer Python-level steps.
    max_batch_elements: cap on tiles x tile-pixels x chunk evaluated at once; bounds the peak
        memory of compositing (about 13 bytes per element) independently of the scene size.
    cull_faint_tiles: leave out of a tile's list each Gaussian whose alpha is below min_alpha at
        every pixel of the tile (the footprint box is a square around the 3-sigma ellipse, so
        elongated footprints touch many such tiles). Same images up to float rounding, less
        compositing work; off by default so depth renders keep their exact historical values.
    """

    near_plane: float = 0.01
    eps2d: float = 0.3
    fov_clamp: float = 1.3
    sigma_extent: float = 3.0
    min_alpha: float = 1.0 / 255.0
    max_alpha: float = 0.99
    stop_transmittance: float = 1e-4
    median_transmittance: float = 0.5
    min_depth_alpha: float = 1e-3
    tile_size: int = 16
    chunk_size: int = 32
    max_batch_elements: int = 1 << 22
    cull_faint_tiles: bool = False
