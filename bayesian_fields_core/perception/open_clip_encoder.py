"""CLIP through the optional ``open_clip`` package (extra ``open_clip``).

For OpenCLIP checkpoints that have no Hugging Face ``CLIPModel`` conversion (e.g. the LAION
ViT-H/14 many open-vocabulary mapping papers use). The operator provides the architecture name
and a local checkpoint file; nothing is downloaded. Preprocessing is open_clip's own transform,
so the embeddings match the checkpoint's training setup.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from bayesian_fields_core.errors import ModelError
from bayesian_fields_core.perception.digest import files_digest
from bayesian_fields_core.perception.encoder import l2_normalize
from bayesian_fields_core.perception.optional import import_extra
from bayesian_fields_core.perception.validation import check_rgb


def open_clip_model_id(model_name: str, checkpoint: str | Path) -> str:
    """``"open_clip:<model name>@<12 hex of the checkpoint's sha256>"``."""
    return f"open_clip:{model_name}@{files_digest([checkpoint])}"


class OpenClipEncoder:
    """``open_clip`` model ``model_name`` with weights from ``checkpoint`` as an ``Encoder``."""

    kind = "open_clip"

    def __init__(self, model_name: str, checkpoint: str | Path, *, device: str = "cpu") -> None:
        open_clip = import_extra("open_clip", "open_clip", "the open_clip encoder")
        import torch

        self.checkpoint = Path(checkpoint)
        if not self.checkpoint.is_file():
            raise ModelError(f"{self.checkpoint}: open_clip checkpoint not found")
        try:
            model, _, preprocess = open_clip.create_model_and_transforms(
                model_name, pretrained=str(self.checkpoint), device=device
            )
        except Exception as exc:  # open_clip raises RuntimeError/KeyError/... for bad checkpoints
            raise ModelError(
                f"{self.checkpoint}: cannot load open_clip model {model_name!r} ({exc})"
            ) from exc
        self._torch = torch
        self.model = model.eval()
        self.device = torch.device(device)
        self.preprocess = preprocess
        self.tokenizer = open_clip.get_tokenizer(model_name)
        self.model_name = model_name
        self.model_id = open_clip_model_id(model_name, self.checkpoint)
        self.dim = int(self.encode_texts(["a"]).shape[1])

    @property
    def params(self) -> dict[str, Any]:
        return {"model_name": self.model_name}

    def encode_images(self, images: list[np.ndarray]) -> np.ndarray:
        """Uint8 RGB images -> ``(M, D)`` float32 unit rows, one batch."""
        from PIL import Image

        if len(images) == 0:
            return np.zeros((0, self.dim), dtype=np.float32)
        torch = self._torch
        batch = torch.stack(
            [self.preprocess(Image.fromarray(check_rgb(im, f"images[{i}]"))) for i, im in enumerate(images)]
        )
        with torch.inference_mode():
            return l2_normalize(self.model.encode_image(batch.to(self.device)).float().cpu().numpy())

    def encode_texts(self, texts: list[str]) -> np.ndarray:
        """Texts -> ``(T, D)`` float32 unit rows."""
        if len(texts) == 0:
            return np.zeros((0, self.dim), dtype=np.float32)
        torch = self._torch
        with torch.inference_mode():
            tokens = self.tokenizer(list(texts)).to(self.device)
            return l2_normalize(self.model.encode_text(tokens).float().cpu().numpy())
