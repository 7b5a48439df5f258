"""Turning images and texts into CLIP model inputs, shared by the HF and ONNX encoders.

Image preprocessing is done here with PIL + numpy from the model folder's
``preprocessor_config.json`` rather than with a transformers image processor, so it needs no
torchvision and behaves the same for the HF and the ONNX backends. Two resize modes:

- ``"shortest_crop"`` (default, what CLIP was trained with): resize the shortest side to ``size``
  (bicubic), then centre-crop to ``crop_size``;
- ``"square"``: resize straight to ``crop_size`` (no pixels lost; distorts non-square inputs; the
  crops from :func:`~bayesian_fields_core.perception.crops.mask_crops` are square by default, so
  both modes agree on them).

Then scale to [0, 1] and normalise with the configured mean/std. Accepted config keys (Hugging Face
``CLIPImageProcessor`` style or a plain one): ``size`` (int, ``{"shortest_edge": n}`` or
``{"height", "width"}``), ``crop_size`` (int or ``{"height", "width"}``), ``image_size`` (int),
``image_mean``/``mean``, ``image_std``/``std``, ``resample`` (PIL code, default bicubic).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
from PIL import Image

from bayesian_fields_core.errors import ModelError
from bayesian_fields_core.perception.validation import check_rgb

ResizeMode = Literal["shortest_crop", "square"]

CLIP_MEAN = (0.48145466, 0.4578275, 0.40821073)
CLIP_STD = (0.26862954, 0.26130258, 0.27577711)
DEFAULT_MAX_TEXT_LENGTH = 77


def _read_json(path: Path) -> dict[str, Any]:
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ModelError(f"{path}: cannot read JSON ({exc})") from exc
    if not isinstance(data, dict):
        raise ModelError(f"{path}: expected a JSON object")
    return data


def _side(value: Any, source: str) -> tuple[int, int] | int | None:
    """An int (shortest edge / square side) or ``(height, width)`` from the config's forms."""
    if value is None:
        return None
    if isinstance(value, int):
        return value
    if isinstance(value, dict):
        if "shortest_edge" in value:
            return int(value["shortest_edge"])
        if "height" in value and "width" in value:
            return int(value["height"]), int(value["width"])
    raise ModelError(f"{source}: unsupported size value {value!r}")


@dataclass(frozen=True)
class ClipImagePreprocessor:
    """Resize, crop and normalise a batch of uint8 RGB images into ``(B, 3, H, W)`` float32."""

    shortest_edge: int
    crop_size: tuple[int, int]
    mean: tuple[float, float, float] = CLIP_MEAN
    std: tuple[float, float, float] = CLIP_STD
    resample: int = int(Image.Resampling.BICUBIC)
    mode: ResizeMode = "shortest_crop"

    @classmethod
    def from_folder(cls, folder: str | Path, mode: ResizeMode = "shortest_crop") -> ClipImagePreprocessor:
        """Read ``preprocessor_config.json`` (falling back to ``config.json``'s vision image size)."""
        folder = Path(folder)
        if mode not in ("shortest_crop", "square"):
            raise ModelError(f"resize mode must be 'shortest_crop' or 'square', got {mode!r}")
        cfg_path = folder / "preprocessor_config.json"
        cfg = _read_json(cfg_path) if cfg_path.is_file() else {}
        fallback = cfg.get("image_size")
        if fallback is None and (folder / "config.json").is_file():
            fallback = _read_json(folder / "config.json").get("vision_config", {}).get("image_size")
        size = _side(cfg.get("size"), str(cfg_path)) or fallback
        crop = _side(cfg.get("crop_size"), str(cfg_path)) or size
        if size is None or crop is None:
            raise ModelError(f"{cfg_path}: no image size (size, crop_size or image_size)")
        crop_hw = crop if isinstance(crop, tuple) else (int(crop), int(crop))
        shortest = size if isinstance(size, int) else min(size)
        mean = tuple(float(v) for v in cfg.get("image_mean", cfg.get("mean", CLIP_MEAN)))
        std = tuple(float(v) for v in cfg.get("image_std", cfg.get("std", CLIP_STD)))
        if len(mean) != 3 or len(std) != 3 or min(std) <= 0:
            raise ModelError(f"{cfg_path}: image mean/std must be 3 values, std > 0")
        resample = int(cfg.get("resample", Image.Resampling.BICUBIC))
        return cls(int(shortest), crop_hw, mean, std, resample, mode)

    def _resize_one(self, image: np.ndarray) -> np.ndarray:
        ch, cw = self.crop_size
        pil = Image.fromarray(image)
        if self.mode == "square":
            return np.asarray(pil.resize((cw, ch), self.resample))
        h, w = image.shape[:2]
        s = self.shortest_edge
        new_h, new_w = (s, int(s * w / h)) if h <= w else (int(s * h / w), s)
        resized = np.asarray(pil.resize((max(new_w, 1), max(new_h, 1)), self.resample))
        # Centre crop; pad with zeros first if the resized image is smaller than the crop.
        pad_h, pad_w = max(ch - resized.shape[0], 0), max(cw - resized.shape[1], 0)
        if pad_h or pad_w:
            resized = np.pad(
                resized, ((pad_h // 2, pad_h - pad_h // 2), (pad_w // 2, pad_w - pad_w // 2), (0, 0))
            )
        top = (resized.shape[0] - ch) // 2
        left = (resized.shape[1] - cw) // 2
        return resized[top : top + ch, left : left + cw]

    def __call__(self, images: list[np.ndarray]) -> np.ndarray:
        """``B`` uint8 images of any size -> ``(B, 3, crop_h, crop_w)`` float32 pixel values."""
        batch = np.stack([self._resize_one(check_rgb(im, f"images[{i}]")) for i, im in enumerate(images)])
        x: np.ndarray = batch.astype(np.float32) / np.float32(255.0)
        x = (x - np.asarray(self.mean, dtype=np.float32)) / np.asarray(self.std, dtype=np.float32)
        return np.ascontiguousarray(x.transpose(0, 3, 1, 2))


class ClipTokenizer:
    """The model folder's tokenizer (``AutoTokenizer``, local files only), padded to the batch's
    longest text and truncated to the text tower's context length."""

    def __init__(self, folder: str | Path) -> None:
        from transformers import AutoTokenizer

        folder = Path(folder)
        try:
            self._tok = AutoTokenizer.from_pretrained(str(folder), local_files_only=True)
        except (OSError, ValueError) as exc:
            raise ModelError(f"{folder}: cannot load the tokenizer ({exc})") from exc
        if self._tok.pad_token is None:
            # CLIP pools at the first end-of-text token, so padding with it is harmless.
            self._tok.pad_token = self._tok.eos_token or self._tok.unk_token
        self.max_length = self._context_length(folder)

    def _context_length(self, folder: Path) -> int:
        config = folder / "config.json"
        if config.is_file():
            n = _read_json(config).get("text_config", {}).get("max_position_embeddings")
            if n:
                return int(n)
        n = getattr(self._tok, "model_max_length", None)
        return int(n) if n and n < 100_000 else DEFAULT_MAX_TEXT_LENGTH

    def __call__(self, texts: list[str]) -> dict[str, np.ndarray]:
        """``{"input_ids", "attention_mask"}`` as int64 ``(T, L)`` arrays."""
        enc = self._tok(
            list(texts), padding=True, truncation=True, max_length=self.max_length, return_tensors="np"
        )
        return {
            "input_ids": np.asarray(enc["input_ids"], dtype=np.int64),
            "attention_mask": np.asarray(enc["attention_mask"], dtype=np.int64),
        }
