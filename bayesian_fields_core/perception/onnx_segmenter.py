"""A class-agnostic segmenter exported to ONNX (e.g. a SAM-like or FastSAM-like model with its
post-processing folded into the graph), run with onnxruntime.

I/O contract the model must follow:
- input (the model's first): float32 ``(1, 3, h, w)`` RGB in [0, 1], the image resized (bilinear,
  aspect not kept) to ``input_size`` = ``(h, w)``;
- output 0: masks ``(1, M, h', w')`` or ``(M, h', w')``, probabilities in [0, 1]
  (``mask_output="probabilities"``) or logits (``"logits"``), at any resolution;
- output 1 (optional): scores ``(1, M)`` or ``(M,)``; masks scoring below ``score_threshold`` are
  dropped.
Masks are resized bilinearly to the image, thresholded at ``threshold`` (a probability), and made
exclusive (smallest wins) with ``min_area``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

import numpy as np
from PIL import Image

from bayesian_fields_core.errors import InputError, ModelError
from bayesian_fields_core.perception.masks import exclusive_labels, resize_masks
from bayesian_fields_core.perception.onnx_clip import onnx_session
from bayesian_fields_core.perception.validation import check_rgb


class OnnxSegmenter:
    """onnxruntime segmenter following the module's I/O contract.

    Parameters: ``path`` (.onnx file), ``input_size`` (int or (h, w); None = the model's static
    input size), ``threshold`` (0.5), ``mask_output`` ("probabilities" or "logits"),
    ``score_threshold`` (0.0), ``min_area`` (100 px), ``providers`` (default CPU), ``threads``.
    """

    name = "onnx"

    def __init__(
        self,
        path: str | Path,
        *,
        input_size: int | tuple[int, int] | None = None,
        threshold: float = 0.5,
        mask_output: Literal["probabilities", "logits"] = "probabilities",
        score_threshold: float = 0.0,
        min_area: int = 100,
        providers: list[str] | None = None,
        threads: int = 0,
    ) -> None:
        self.path = Path(path)
        if mask_output not in ("probabilities", "logits"):
            raise InputError(
                f"must be 'probabilities' or 'logits', got {mask_output!r}", source="mask_output"
            )
        if not 0.0 < threshold < 1.0:
            raise InputError(f"must be in (0, 1), got {threshold}", source="threshold")
        self._session = onnx_session(self.path, providers, threads)
        inp = self._session.get_inputs()[0]
        self._input = inp.name
        if input_size is None:
            h, w = inp.shape[2:4] if len(inp.shape) == 4 else (None, None)
            if not (isinstance(h, int) and isinstance(w, int)):
                raise ModelError(f"{self.path}: the model's input size is dynamic; set input_size")
            input_size = (h, w)
        self.input_size = (input_size, input_size) if isinstance(input_size, int) else tuple(input_size)
        self.threshold = float(threshold)
        self.mask_output = mask_output
        self.score_threshold = float(score_threshold)
        self.min_area = int(min_area)

    @property
    def params(self) -> dict[str, Any]:
        return {
            "model": self.path.name,
            "input_size": list(self.input_size),
            "threshold": self.threshold,
            "mask_output": self.mask_output,
            "score_threshold": self.score_threshold,
            "min_area": self.min_area,
        }

    def segment(self, image: np.ndarray) -> np.ndarray:
        """``(H, W, 3) uint8`` RGB -> ``(H, W) int32`` exclusive labels."""
        check_rgb(image)
        height, width = image.shape[:2]
        h, w = self.input_size
        resized = np.asarray(Image.fromarray(image).resize((w, h), Image.Resampling.BILINEAR))
        x = np.ascontiguousarray((resized.astype(np.float32) / 255.0).transpose(2, 0, 1)[None])
        outputs = self._session.run(None, {self._input: x})
        masks: np.ndarray = np.asarray(outputs[0], dtype=np.float32)
        if masks.ndim == 4:
            masks = masks[0]
        if masks.ndim != 3:
            raise ModelError(f"{self.path}: mask output must be (1, M, h, w) or (M, h, w), got {masks.shape}")
        if self.mask_output == "logits":
            masks = 1.0 / (1.0 + np.exp(-masks))
        if len(outputs) > 1 and self.score_threshold > 0.0:
            scores = np.asarray(outputs[1], dtype=np.float32).reshape(-1)
            if scores.shape[0] != masks.shape[0]:
                raise ModelError(f"{self.path}: {scores.shape[0]} scores for {masks.shape[0]} masks")
            masks = masks[scores >= self.score_threshold]
        return exclusive_labels(resize_masks(masks, height, width, threshold=self.threshold), self.min_area)
