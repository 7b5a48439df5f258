"""A classical (no weights) over-segmenter: scikit-image Felzenszwalb or SLIC.

It is the fallback when no learned segmenter is configured and the segmenter of the tests and the
bundled default profile: deterministic, CPU-only, no model files. Superpixels are already
exclusive, so the only post-processing is dropping regions below ``min_area`` and renumbering.
Large images can be downscaled to ``max_side`` for speed; labels are brought back to full size by
nearest-neighbour lookup, which keeps them exclusive.
"""

from __future__ import annotations

from typing import Any, Literal

import numpy as np
from PIL import Image
from skimage.segmentation import felzenszwalb, slic

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.perception.masks import filter_small_labels
from bayesian_fields_core.perception.validation import check_rgb

Method = Literal["felzenszwalb", "slic"]


def upsample_labels_nearest(labels: np.ndarray, height: int, width: int) -> np.ndarray:
    """Resize a label image to ``(height, width)`` by nearest neighbour (pixel-centre sampling)."""
    h, w = labels.shape
    rows = np.minimum(((np.arange(height) + 0.5) * (h / height)).astype(np.int64), h - 1)
    cols = np.minimum(((np.arange(width) + 0.5) * (w / width)).astype(np.int64), w - 1)
    return labels[rows[:, None], cols[None, :]]


class ClassicalSegmenter:
    """Felzenszwalb (default) or SLIC superpixels as exclusive labels.

    Parameters (defaults chosen for ~640 px images of indoor scenes: regions of object-part size):
    - ``method``: ``"felzenszwalb"`` or ``"slic"``.
    - ``scale`` (300), ``sigma`` (0.8), ``min_size`` (50): Felzenszwalb's; a larger ``scale`` gives
      larger regions. ``scale`` and ``min_size`` apply at the working resolution (after downscale).
    - ``n_segments`` (100), ``compactness`` (10.0): SLIC's.
    - ``min_area`` (64): regions with fewer full-resolution pixels are dropped (label -1).
    - ``max_side`` (640): the longer image side is downscaled to this (area averaging) before segmenting; ``None``
      segments at full resolution.
    """

    name = "classical"

    def __init__(
        self,
        method: Method = "felzenszwalb",
        *,
        scale: float = 300.0,
        sigma: float = 0.8,
        min_size: int = 50,
        n_segments: int = 100,
        compactness: float = 10.0,
        min_area: int = 64,
        max_side: int | None = 640,
    ) -> None:
        if method not in ("felzenszwalb", "slic"):
            raise InputError(f"unknown method {method!r} (felzenszwalb or slic)", source="segmenter.method")
        if max_side is not None and max_side < 8:
            raise InputError(f"must be >= 8 or null, got {max_side}", source="segmenter.max_side")
        self.method: Method = method
        self.scale = float(scale)
        self.sigma = float(sigma)
        self.min_size = int(min_size)
        self.n_segments = int(n_segments)
        self.compactness = float(compactness)
        self.min_area = int(min_area)
        self.max_side = None if max_side is None else int(max_side)

    @property
    def params(self) -> dict[str, Any]:
        """The parameters that change the output (for the cache fingerprint)."""
        common = {"method": self.method, "min_area": self.min_area, "max_side": self.max_side}
        if self.method == "felzenszwalb":
            return common | {"scale": self.scale, "sigma": self.sigma, "min_size": self.min_size}
        return common | {"n_segments": self.n_segments, "compactness": self.compactness, "sigma": self.sigma}

    def segment(self, image: np.ndarray) -> np.ndarray:
        """``(H, W, 3) uint8`` -> ``(H, W) int32`` exclusive labels (-1 = none)."""
        check_rgb(image)
        height, width = image.shape[:2]
        work = image
        if self.max_side is not None and max(height, width) > self.max_side:
            factor = self.max_side / max(height, width)
            size = (max(1, round(width * factor)), max(1, round(height * factor)))
            work = np.asarray(Image.fromarray(image).resize(size, Image.Resampling.BOX))
        if self.method == "felzenszwalb":
            raw = felzenszwalb(work, scale=self.scale, sigma=self.sigma, min_size=self.min_size)
        else:
            raw = slic(
                work,
                n_segments=self.n_segments,
                compactness=self.compactness,
                sigma=self.sigma,
                start_label=0,
                channel_axis=-1,
            )
        if raw.shape != (height, width):
            raw = upsample_labels_nearest(raw, height, width)
        return filter_small_labels(raw.astype(np.int64), self.min_area)
