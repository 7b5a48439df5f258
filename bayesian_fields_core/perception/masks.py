"""Exclusive label images from overlapping masks, and per-label boxes and areas.

Class-agnostic segmenters (FastSAM, SAM-like ONNX models) return overlapping masks: a whole table
and the cup on it. The fusion step needs every pixel to belong to at most one mask, so that a
Gaussian seen at that pixel is associated with exactly one measurement. Following the method, masks
are painted largest-first so the smallest mask covering a pixel wins (the cup keeps its pixels, the
table keeps the rest). Masks are painted with one vectorised assignment each and areas come from
``bincount``; there is no loop over pixels.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from bayesian_fields_core.errors import InputError

__all__ = [
    "exclusive_assignment",
    "exclusive_labels",
    "filter_small_labels",
    "label_areas",
    "label_boxes",
    "resize_masks",
]


def exclusive_assignment(masks: np.ndarray, min_area: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Exclusive labels plus, for each output label, the index of the input mask it came from.

    Steps (all vectorised):
    1. masks whose full area is below ``min_area`` are dropped before painting, so a speck never
       steals pixels from the larger mask around it;
    2. every pixel takes the smallest covering mask (ties: the lower input index): masks are
       ranked by area once (argsort) and painted largest-first, each paint one vectorised boolean
       assignment over the whole frame. This loops over masks (~100), never over pixels; measured
       on 100 masks at 640x480 it takes 23 ms, against 250 ms for a single ``np.minimum.at``
       scatter over all mask pixels and 350 ms for an ``argmax`` over the stacked masks;
    3. masks whose *remaining* (exclusive) area is below ``min_area`` are dropped (their pixels
       become -1) and the survivors are renumbered ``0..K-1`` in input order.

    Returns ``(labels (H, W) int32, source (K,) int64)`` where ``source[k]`` is the input index of
    label ``k`` (used to carry per-mask scores along).
    """
    masks = np.asarray(masks)
    if masks.ndim != 3:
        raise InputError(f"expected masks of shape (M, H, W), got {masks.shape}", source="masks")
    if min_area < 0:
        raise InputError(f"must be >= 0, got {min_area}", source="min_area")
    m, h, w = masks.shape
    masks = masks.astype(bool, copy=False).reshape(m, h * w)
    labels = np.full(h * w, -1, dtype=np.int32)
    if m == 0:
        return labels.reshape(h, w), np.zeros(0, dtype=np.int64)

    areas = masks.sum(axis=1)
    candidates = np.flatnonzero(areas >= max(min_area, 1))
    # Rank candidates by area ascending; stable sort keeps the lower index first among ties.
    order = candidates[np.argsort(areas[candidates], kind="stable")]
    rank_of = np.full(m, m, dtype=np.int64)
    rank_of[order] = np.arange(order.size)

    best = np.full(h * w, order.size, dtype=np.int64)  # rank of the winning mask; size = none
    for rank in range(order.size - 1, -1, -1):  # largest first, so smaller masks overwrite
        best[masks[order[rank]]] = rank

    covered = best < order.size
    remaining = np.bincount(best[covered], minlength=order.size)
    keep_rank = remaining >= max(min_area, 1)
    # Renumber survivors in input order.
    source = np.sort(order[keep_rank])
    new_id = np.full(order.size + 1, -1, dtype=np.int32)
    new_id[rank_of[source]] = np.arange(source.size, dtype=np.int32)
    labels = new_id[best]  # best == order.size maps to the trailing -1
    return labels.reshape(h, w), source.astype(np.int64)


def exclusive_labels(masks: np.ndarray, min_area: int = 0) -> np.ndarray:
    """``(M, H, W)`` bool masks to an ``(H, W)`` int32 label image (-1 = no mask); see
    :func:`exclusive_assignment` for the painting and filtering rules."""
    return exclusive_assignment(masks, min_area)[0]


def filter_small_labels(labels: np.ndarray, min_area: int) -> np.ndarray:
    """Drop labels with fewer than ``min_area`` pixels (set to -1) and renumber the rest ``0..K-1``
    keeping their order. For segmenters that already produce exclusive labels (Felzenszwalb, SLIC).
    """
    labels = np.asarray(labels)
    flat = labels.ravel()
    valid = flat >= 0
    if not valid.any():
        return np.full(labels.shape, -1, dtype=np.int32)
    counts = np.bincount(flat[valid])
    keep = counts >= max(min_area, 1)
    new_id = np.full(counts.size + 1, -1, dtype=np.int32)
    new_id[:-1][keep] = np.arange(int(keep.sum()), dtype=np.int32)
    # -1 indexes the trailing sentinel.
    return new_id[np.where(valid, flat, -1)].reshape(labels.shape)


def label_areas(labels: np.ndarray, num_labels: int | None = None) -> np.ndarray:
    """Pixel count of each label ``0..M-1`` as int64 ``(M,)``."""
    flat = np.asarray(labels).ravel()
    n = int(flat.max()) + 1 if num_labels is None and flat.size else int(num_labels or 0)
    return np.bincount(flat[flat >= 0], minlength=n)[:n].astype(np.int64)


def label_boxes(labels: np.ndarray, num_labels: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Bounding box and area of each label of an exclusive label image.

    Returns ``(boxes (M, 4) int64, areas (M,) int64)`` with boxes as ``(x0, y0, x1, y1)`` in pixels,
    end-exclusive (so ``image[y0:y1, x0:x1]`` is the crop). ``M`` defaults to ``labels.max() + 1``;
    a label with no pixels gets the box ``(0, 0, 0, 0)`` and area 0.
    """
    labels = np.asarray(labels)
    if labels.ndim != 2:
        raise InputError(f"expected an (H, W) label image, got {labels.shape}", source="labels")
    n = (int(labels.max()) + 1 if labels.size else 0) if num_labels is None else int(num_labels)
    n = max(n, 0)
    boxes = np.zeros((n, 4), dtype=np.int64)
    if n == 0:
        return boxes, np.zeros(0, dtype=np.int64)
    # find_objects ignores 0, so shift labels by one (-1 "none" becomes 0).
    slices = ndimage.find_objects(labels.astype(np.int64) + 1, max_label=n)
    present = np.array([s is not None for s in slices], dtype=bool)
    if present.any():
        spans = np.array(
            [(s[1].start, s[0].start, s[1].stop, s[0].stop) for s in slices if s is not None],
            dtype=np.int64,
        )
        boxes[present] = spans
    return boxes, label_areas(labels, n)


def resize_masks(
    probs: np.ndarray, height: int, width: int, *, threshold: float = 0.5, chunk: int = 16
) -> np.ndarray:
    """Soft masks ``(M, h, w)`` (probabilities) -> ``(M, height, width)`` bool.

    Bilinear interpolation of the probabilities, then the threshold: smoother boundaries than
    thresholding first and upsampling the bits. Done in chunks of ``chunk`` masks so the float
    buffer stays small for large frames (the bool result is 1 byte per pixel per mask).
    """
    import torch
    import torch.nn.functional as F

    probs = np.asarray(probs, dtype=np.float32)
    m = probs.shape[0]
    out = np.empty((m, height, width), dtype=bool)
    if probs.shape[1:] == (height, width):
        np.greater(probs, threshold, out=out)
        return out
    src = torch.from_numpy(np.ascontiguousarray(probs))
    for start in range(0, m, chunk):
        part = F.interpolate(
            src[start : start + chunk, None], size=(height, width), mode="bilinear", align_corners=False
        )
        out[start : start + chunk] = (part[:, 0] > threshold).numpy()
    return out
