"""Input checks shared by the segmenters, encoders and crop helpers.

Images reach perception from decoders, renderers and user uploads; checking the dtype and shape at
the boundary turns a confusing error deep inside skimage/torch into one naming the problem.
"""

from __future__ import annotations

import numpy as np

from bayesian_fields_core.errors import InputError


def check_rgb(image: np.ndarray, what: str = "image") -> np.ndarray:
    """Return ``image`` if it is an ``(H, W, 3)`` uint8 array with H, W >= 1; raise InputError."""
    if not isinstance(image, np.ndarray):
        raise InputError(f"expected a numpy array, got {type(image).__name__}", source=what)
    if image.dtype != np.uint8:
        raise InputError(f"expected dtype uint8, got {image.dtype}", source=what)
    if image.ndim != 3 or image.shape[2] != 3 or image.shape[0] < 1 or image.shape[1] < 1:
        raise InputError(f"expected shape (H, W, 3), got {image.shape}", source=what)
    return image


def check_labels(labels: np.ndarray, shape: tuple[int, int], what: str = "labels") -> np.ndarray:
    """Return ``labels`` if it is an integer ``(H, W)`` array matching ``shape``; raise InputError."""
    if not isinstance(labels, np.ndarray) or not np.issubdtype(labels.dtype, np.integer):
        raise InputError("expected an integer numpy array", source=what)
    if labels.shape != tuple(shape):
        raise InputError(f"shape {labels.shape} does not match the image {tuple(shape)}", source=what)
    return labels
