"""Per-pixel id images of a splat: which labelled group of Gaussians dominates each pixel.

Used for GT instance masks (LeRF-style evaluation, CLIP training crops) and for rendering a map's
object ids. The renderer only composites colours, so ids are encoded as colours: each id gets a
code on a 5-level RGB lattice (124 codes per pass, black meaning "no id"), the view is rendered
over black, the colour is divided by alpha (the opacity-weighted mean code) and decoded by
rounding. Pixels whose mean colour is not close to one lattice point (mixtures at boundaries) or
whose alpha is low get -1. More than 124 ids take several passes, each encoding one slice.
"""

from __future__ import annotations

import numpy as np

from bayesian_fields_core.geometry.spherical_harmonics import SH_C0
from bayesian_fields_core.render import GaussianRenderer
from bayesian_fields_core.scene.types import Gaussians

LEVELS = 5
CODES_PER_PASS = LEVELS**3 - 1


def _coded(gaussians: Gaussians, codes: np.ndarray) -> Gaussians:
    """The same Gaussians with degree-0 colours set to codes (n, 3) in [0, 1]."""
    sh = np.zeros((len(gaussians), 1, 3), dtype=np.float32)
    sh[:, 0, :] = (codes - 0.5) / SH_C0
    return Gaussians(gaussians.means, gaussians.log_scales, gaussians.quats, gaussians.opacity_logits, sh)


def _lattice(index: np.ndarray) -> np.ndarray:
    """Code colour of lattice index 1..124 (0 is black)."""
    digits = np.stack([index // LEVELS**2, (index // LEVELS) % LEVELS, index % LEVELS], axis=-1)
    return digits / (LEVELS - 1)


def _erode_inconsistent(ids: np.ndarray) -> np.ndarray:
    """Set -1 where a 4-neighbour carries another id: mixtures along a boundary between two codes
    can average to a third code, which shows up as thin lines of a wrong id; real regions survive
    with a one-pixel rim removed."""
    padded = np.pad(ids, 1, mode="edge")
    centre = padded[1:-1, 1:-1]
    same = (
        (padded[:-2, 1:-1] == centre)
        & (padded[2:, 1:-1] == centre)
        & (padded[1:-1, :-2] == centre)
        & (padded[1:-1, 2:] == centre)
    )
    return np.where(same, ids, -1)


class IdImageRenderer:
    """Renders id images of one splat for many cameras (the coded splats stay resident).

    ids: (N,) integer per-Gaussian id, any value < 0 meaning "no id" (such Gaussians still
    occlude). alpha_threshold: minimum accumulated opacity for a pixel to get an id.
    tolerance: largest distance, in lattice steps per channel, between a pixel's mean colour
    and the lattice point it is decoded to.
    """

    def __init__(
        self,
        gaussians: Gaussians,
        ids: np.ndarray,
        *,
        alpha_threshold: float = 0.5,
        tolerance: float = 0.3,
        device: str = "cpu",
    ) -> None:
        ids = np.asarray(ids).astype(np.int64)
        if ids.shape != (len(gaussians),):
            raise ValueError(f"ids has shape {ids.shape}, expected ({len(gaussians)},)")
        self.labels, dense = np.unique(ids[ids >= 0], return_inverse=True)
        dense_all = np.full(len(gaussians), -1, dtype=np.int64)
        dense_all[ids >= 0] = dense
        self.alpha_threshold = alpha_threshold
        self.tolerance = tolerance
        self.renderers = []
        for start in range(0, max(len(self.labels), 1), CODES_PER_PASS):
            local = dense_all - start
            inside = (local >= 0) & (local < CODES_PER_PASS)
            codes = np.where(inside[:, None], _lattice(np.where(inside, local + 1, 0)), 0.0)
            self.renderers.append(
                (start, GaussianRenderer(_coded(gaussians, codes), device=device, backend="torch"))
            )

    def render(self, K: np.ndarray, world_to_camera: np.ndarray, width: int, height: int) -> np.ndarray:
        """(H, W) int64 id image; -1 where no id dominates."""
        out = np.full((height, width), -1, dtype=np.int64)
        for start, renderer in self.renderers:
            res = renderer.render(K, world_to_camera, width, height, background=(0.0, 0.0, 0.0))
            ok = res.alpha >= self.alpha_threshold
            mean = res.rgb / np.maximum(res.alpha, 1e-6)[..., None] * (LEVELS - 1)
            digits = np.rint(mean)
            ok &= np.all(np.abs(mean - digits) <= self.tolerance, axis=-1)
            d = np.clip(digits.astype(np.int64), 0, LEVELS - 1)
            index = d[..., 0] * LEVELS**2 + d[..., 1] * LEVELS + d[..., 2]
            ok &= (index > 0) & (start + index - 1 < len(self.labels))
            out[ok] = self.labels[start + index[ok] - 1]
        return _erode_inconsistent(out)
