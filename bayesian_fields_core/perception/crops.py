"""Per-mask image crops for the CLIP encoder, and embedding all masks of a frame in one batch.

Each mask is cropped to its bounding box, grown by ``pad_fraction`` of the box's longer side for a
little context, made square (CLIP's input is square; a square crop is not distorted by the
resize), and pixels outside the mask are replaced by a flat background so the embedding describes
the segment rather than its surroundings (the method's "masked segment"). Windows that reach past
the image border are filled with the background too, which keeps the object centred.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.perception.encoder import Encoder
from bayesian_fields_core.perception.masks import label_boxes
from bayesian_fields_core.perception.validation import check_labels, check_rgb

Background = Literal["gray", "black", "keep"]
GRAY = 128


def crop_windows(boxes: np.ndarray, pad_fraction: float, square: bool) -> np.ndarray:
    """Grow ``(M, 4)`` ``(x0, y0, x1, y1)`` boxes by ``pad_fraction`` of their longer side on every
    side, and to a square around the box centre when ``square``; may extend past the image."""
    boxes = boxes.astype(np.float64)
    w = boxes[:, 2] - boxes[:, 0]
    h = boxes[:, 3] - boxes[:, 1]
    side = np.maximum(w, h)
    pad = np.ceil(pad_fraction * side)
    if square:
        half = (side + 2 * pad) / 2
        cx, cy = (boxes[:, 0] + boxes[:, 2]) / 2, (boxes[:, 1] + boxes[:, 3]) / 2
        x0, y0 = np.floor(cx - half), np.floor(cy - half)
        size = np.ceil(side + 2 * pad)
        return np.stack([x0, y0, x0 + size, y0 + size], axis=1).astype(np.int64)
    return np.stack(
        [boxes[:, 0] - pad, boxes[:, 1] - pad, boxes[:, 2] + pad, boxes[:, 3] + pad], axis=1
    ).astype(np.int64)


def mask_crops(
    image: np.ndarray,
    labels: np.ndarray,
    *,
    background: Background = "gray",
    pad_fraction: float = 0.1,
    square: bool = True,
) -> list[np.ndarray]:
    """One uint8 crop per label ``0..M-1`` (``M = labels.max() + 1``), in label order.

    ``background``: "gray" (128; default, close to CLIP's mean colour, so it carries little
    signal), "black", or "keep" (original pixels around the mask; only out-of-image area is gray).
    A label with no pixels gets a 1x1 background crop so the output stays aligned with the labels.
    """
    check_rgb(image)
    check_labels(labels, image.shape[:2])
    if background not in ("gray", "black", "keep"):
        raise InputError(f"must be 'gray', 'black' or 'keep', got {background!r}", source="background")
    if pad_fraction < 0:
        raise InputError(f"must be >= 0, got {pad_fraction}", source="pad_fraction")
    boxes, areas = label_boxes(labels)
    windows = crop_windows(boxes, pad_fraction, square)
    height, width = labels.shape
    fill = 0 if background == "black" else GRAY
    crops: list[np.ndarray] = []
    for k in range(boxes.shape[0]):  # per mask, never per pixel
        if areas[k] == 0:
            crops.append(np.full((1, 1, 3), fill, dtype=np.uint8))
            continue
        x0, y0, x1, y1 = windows[k]
        out = np.full((y1 - y0, x1 - x0, 3), GRAY if background == "keep" else fill, dtype=np.uint8)
        cx0, cy0, cx1, cy1 = max(x0, 0), max(y0, 0), min(x1, width), min(y1, height)
        region = image[cy0:cy1, cx0:cx1]
        dst = out[cy0 - y0 : cy1 - y0, cx0 - x0 : cx1 - x0]
        if background == "keep":
            dst[...] = region
        else:
            inside = (labels[cy0:cy1, cx0:cx1] == k)[..., None]
            np.copyto(dst, region, where=inside)
        crops.append(out)
    return crops


def embed_masks(
    encoder: Encoder,
    image: np.ndarray,
    labels: np.ndarray,
    *,
    background: Background = "gray",
    pad_fraction: float = 0.1,
    square: bool = True,
) -> np.ndarray:
    """``(M, D)`` float32 unit embeddings of every mask of a frame, encoded in one batch.

    A frame with no masks gives ``(0, D)`` without calling the model.
    """
    crops = mask_crops(image, labels, background=background, pad_fraction=pad_fraction, square=square)
    if not crops:
        return np.zeros((0, encoder.dim), dtype=np.float32)
    return encoder.encode_images(crops)
