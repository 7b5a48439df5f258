"""FastSAM (the paper's segmenter) through the optional, AGPL-licensed ``ultralytics`` package.

Install with the ``fastsam`` extra; the operator provides the weights file (``FastSAM-s.pt`` or
``FastSAM-x.pt``); nothing is downloaded (a missing file is an error before ultralytics could try).
ultralytics writes a settings file under the user's config dir; unless ``YOLO_CONFIG_DIR`` is set,
we point it at a temp folder so read-only homes (containers) work, and set ``YOLO_OFFLINE``.

FastSAM returns overlapping masks; :func:`fastsam_masks_to_labels` turns them into exclusive
labels (smallest wins), undoing ultralytics' letterbox when the masks are at inference resolution
(``retina_masks=False``).
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from bayesian_fields_core.errors import InputError, ModelError
from bayesian_fields_core.perception.masks import exclusive_labels, resize_masks
from bayesian_fields_core.perception.optional import import_extra
from bayesian_fields_core.perception.validation import check_rgb


def unletterbox(masks: np.ndarray, height: int, width: int) -> np.ndarray:
    """Crop the centred letterbox padding off ``(M, h, w)`` masks computed for a ``(height, width)``
    image (aspect kept, scaled by ``min(h/height, w/width)``, padding split evenly)."""
    _, h, w = masks.shape
    gain = min(h / height, w / width)
    inner_h, inner_w = round(height * gain), round(width * gain)
    top = round((h - inner_h) / 2 - 0.1)
    left = round((w - inner_w) / 2 - 0.1)
    return masks[:, top : top + inner_h, left : left + inner_w]


def fastsam_masks_to_labels(
    masks: np.ndarray, image_shape: tuple[int, int], *, min_area: int, threshold: float = 0.5
) -> np.ndarray:
    """FastSAM mask data ``(M, h, w)`` (bool or probabilities) -> exclusive ``(H, W)`` int32 labels.

    Masks at the image's resolution (``retina_masks=True``) are used as they are; smaller ones are
    un-letterboxed and resized bilinearly first.
    """
    masks = np.asarray(masks)
    if masks.ndim != 3:
        raise InputError(f"expected (M, h, w) masks, got {masks.shape}", source="fastsam masks")
    height, width = image_shape
    if masks.shape[1:] != (height, width):
        masks = resize_masks(
            unletterbox(masks.astype(np.float32), height, width), height, width, threshold=threshold
        )
    else:
        masks = masks > threshold if masks.dtype != bool else masks
    return exclusive_labels(masks, min_area)


def _precision_args(half: bool) -> dict[str, Any]:
    """ultralytics' keyword for fp16 inference: `half=True` until 8.4, `quantize=16` since (where
    `half` still works but warns on every call and is to be removed); nothing for fp32."""
    if not half:
        return {}
    from ultralytics.cfg import DEFAULT_CFG_DICT

    return {"quantize": 16} if "quantize" in DEFAULT_CFG_DICT else {"half": True}


class FastSAMSegmenter:
    """FastSAM via ultralytics as a ``Segmenter``.

    Parameters (ultralytics' predict arguments, FastSAM's published defaults): ``weights`` (path),
    ``conf`` (0.4), ``iou`` (0.9), ``imgsz`` (1024), ``retina_masks`` (True: masks at full image
    resolution), ``device`` ("cpu", "cuda:0", ...), ``min_area`` (100 px, after exclusivity),
    ``threshold`` (0.5, only for masks that come back as probabilities).
    """

    name = "fastsam"

    def __init__(
        self,
        weights: str | Path,
        *,
        conf: float = 0.4,
        iou: float = 0.9,
        imgsz: int = 1024,
        retina_masks: bool = True,
        device: str = "cpu",
        min_area: int = 100,
        threshold: float = 0.5,
        half: bool = False,
    ) -> None:
        os.environ.setdefault("YOLO_CONFIG_DIR", str(Path(tempfile.gettempdir()) / "bfields-ultralytics"))
        os.environ.setdefault("YOLO_OFFLINE", "1")
        ultralytics = import_extra("ultralytics", "fastsam", "the FastSAM segmenter")
        self.weights = Path(weights)
        if not self.weights.is_file():
            raise ModelError(f"{self.weights}: FastSAM weights not found")
        try:
            self.model = ultralytics.FastSAM(str(self.weights))
        except Exception as exc:  # ultralytics raises assorted errors for bad checkpoints
            raise ModelError(f"{self.weights}: cannot load FastSAM ({exc})") from exc
        self.conf, self.iou, self.imgsz = float(conf), float(iou), int(imgsz)
        self.retina_masks, self.device = bool(retina_masks), device
        self.min_area, self.threshold = int(min_area), float(threshold)
        self.half = bool(half)  # fp16 inference (a GPU's tensor cores); masks may differ slightly
        self._precision = _precision_args(self.half)

    @property
    def params(self) -> dict[str, Any]:
        return {
            "weights": self.weights.name,
            "conf": self.conf,
            "iou": self.iou,
            "imgsz": self.imgsz,
            "retina_masks": self.retina_masks,
            "min_area": self.min_area,
            "threshold": self.threshold,
            # Only when set, so fp32 fingerprints (and the caches keyed on them) stay as they were.
            **({"half": True} if self.half else {}),
        }

    def segment(self, image: np.ndarray) -> np.ndarray:
        """``(H, W, 3) uint8`` RGB -> ``(H, W) int32`` exclusive labels."""
        check_rgb(image)
        bgr = np.ascontiguousarray(image[..., ::-1])  # ultralytics reads numpy arrays as BGR
        results = self.model(
            bgr,
            device=self.device,
            retina_masks=self.retina_masks,
            imgsz=self.imgsz,
            conf=self.conf,
            iou=self.iou,
            verbose=False,
            **self._precision,
        )
        masks = results[0].masks if results else None
        if masks is None:
            return np.full(image.shape[:2], -1, dtype=np.int32)
        data = masks.data.float().cpu().numpy()
        return fastsam_masks_to_labels(
            data, image.shape[:2], min_area=self.min_area, threshold=self.threshold
        )
