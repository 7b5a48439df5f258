"""CLIP through Hugging Face transformers (``CLIPModel`` from a local folder).

The folder is what ``save_pretrained`` writes (``config.json`` + safetensors weights) plus the
tokenizer files and ``preprocessor_config.json``. Nothing is downloaded (``local_files_only``).
Images are preprocessed by :class:`~bayesian_fields_core.perception.clip_inputs.ClipImagePreprocessor`
(no torchvision). All images of a call go through the model in one batch (optionally split into
``max_batch`` chunks to bound memory).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch

from bayesian_fields_core.errors import ModelError
from bayesian_fields_core.perception.clip_inputs import ClipImagePreprocessor, ClipTokenizer, ResizeMode
from bayesian_fields_core.perception.digest import files_digest
from bayesian_fields_core.perception.encoder import l2_normalize


def weight_files(folder: str | Path) -> list[Path]:
    """The checkpoint files of a ``save_pretrained`` folder (safetensors preferred)."""
    folder = Path(folder)
    files = sorted(folder.glob("*.safetensors")) or sorted(folder.glob("pytorch_model*.bin"))
    if not files:
        raise ModelError(f"{folder}: no model weights (*.safetensors) found")
    return files


def hf_clip_model_id(folder: str | Path) -> str:
    """``"<folder name>@<12 hex of the weights' sha256>"``: names the exact weights, not the path.

    Calibration files (``calibration.json``'s ``model_id``) must carry this value.
    """
    folder = Path(folder)
    return f"{folder.resolve().name}@{files_digest(weight_files(folder))}"


def _embeddings(output: Any, kind: str) -> torch.Tensor:
    """The projected embeddings from ``get_*_features``: a tensor (transformers 4) or a ModelOutput
    whose ``pooler_output`` holds the projection (transformers 5)."""
    if isinstance(output, torch.Tensor):
        return output
    for attr in (f"{kind}_embeds", "pooler_output"):
        value = getattr(output, attr, None)
        if isinstance(value, torch.Tensor):
            return value
    raise ModelError(f"unexpected output of get_{kind}_features: {type(output).__name__}")


class HFClipEncoder:
    """A transformers ``CLIPModel`` as an :class:`~bayesian_fields_core.perception.encoder.Encoder`.

    Parameters: ``path`` (model folder), ``device`` ("cpu", "cuda", "cuda:1"...), ``resize_mode``
    ("shortest_crop" or "square", see ``clip_inputs``), ``max_batch`` (None = one batch per call),
    ``dtype`` ("float32"; "float16" or "bfloat16" on a GPU halves memory and uses tensor cores).
    """

    kind = "hf_clip"

    def __init__(
        self,
        path: str | Path,
        *,
        device: str = "cpu",
        resize_mode: ResizeMode = "shortest_crop",
        max_batch: int | None = None,
        dtype: str = "float32",
    ) -> None:
        from transformers import CLIPModel

        self.path = Path(path)
        if not (self.path / "config.json").is_file():
            raise ModelError(f"{self.path}: not a CLIP model folder (config.json missing)")
        self.model_id = hf_clip_model_id(self.path)
        try:
            model = CLIPModel.from_pretrained(str(self.path), local_files_only=True)
        except (OSError, ValueError) as exc:
            raise ModelError(f"{self.path}: cannot load CLIPModel ({exc})") from exc
        if dtype not in ("float32", "float16", "bfloat16"):
            raise ModelError(f"dtype must be float32, float16 or bfloat16, got {dtype!r}")
        self.dtype = getattr(torch, dtype)
        self.device = torch.device(device)
        self.model = model.eval().to(self.device, dtype=self.dtype)
        if model.config.projection_dim is None:
            raise ModelError(f"{self.path}: the model's config has no projection_dim")
        self.dim = int(model.config.projection_dim)
        self.preprocess = ClipImagePreprocessor.from_folder(self.path, resize_mode)
        self.tokenizer = ClipTokenizer(self.path)
        if max_batch is not None and max_batch < 1:
            raise ModelError(f"max_batch must be >= 1, got {max_batch}")
        self.max_batch = max_batch

    @property
    def params(self) -> dict[str, Any]:
        """Settings that change the embeddings (for the cache fingerprint)."""
        extra = {} if self.dtype == torch.float32 else {"dtype": str(self.dtype).removeprefix("torch.")}
        return {"resize_mode": self.preprocess.mode, **extra}

    def _chunks(self, n: int) -> list[slice]:
        step = self.max_batch or max(n, 1)
        return [slice(i, i + step) for i in range(0, n, step)]

    def encode_images(self, images: list[np.ndarray]) -> np.ndarray:
        """Uint8 RGB images -> ``(M, D)`` float32 unit rows."""
        if len(images) == 0:
            return np.zeros((0, self.dim), dtype=np.float32)
        pixels = self.preprocess(images)
        out = []
        with torch.inference_mode():
            for part in self._chunks(len(images)):
                x = torch.from_numpy(pixels[part]).to(self.device, dtype=self.dtype)
                out.append(_embeddings(self.model.get_image_features(pixel_values=x), "image").float().cpu())
        return l2_normalize(torch.cat(out).numpy())

    def encode_texts(self, texts: list[str]) -> np.ndarray:
        """Texts -> ``(T, D)`` float32 unit rows."""
        if len(texts) == 0:
            return np.zeros((0, self.dim), dtype=np.float32)
        enc = self.tokenizer(texts)
        with torch.inference_mode():
            ids = torch.from_numpy(enc["input_ids"]).to(self.device)
            mask = torch.from_numpy(enc["attention_mask"]).to(self.device)
            feats = self.model.get_text_features(input_ids=ids, attention_mask=mask)
            return l2_normalize(_embeddings(feats, "text").float().cpu().numpy())
