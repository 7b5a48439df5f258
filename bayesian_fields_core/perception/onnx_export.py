"""Export a Hugging Face CLIP folder to the two-file ONNX layout that ``OnnxClipEncoder`` reads.

Deployments without PyTorch (or with a faster ONNX runtime provider) run the towers through
onnxruntime. The output folder holds:

- ``image_encoder.onnx``: input ``pixel_values`` float32 ``(B, 3, S, S)``; output ``image_embeds``
  float32 ``(B, D)`` (projected, not normalised);
- ``text_encoder.onnx``: inputs ``input_ids`` and ``attention_mask`` int64 ``(B, L)``; output
  ``text_embeds`` float32 ``(B, D)``;
- the tokenizer files, ``preprocessor_config.json`` and ``config.json`` copied from the source.

Uses the TorchScript-based exporter (``dynamo=False``), which needs no ``onnxscript``.
"""

from __future__ import annotations

import shutil
import warnings
from pathlib import Path
from typing import TYPE_CHECKING

import torch

from bayesian_fields_core.errors import ModelError
from bayesian_fields_core.perception.hf_clip import _embeddings

if TYPE_CHECKING:
    from transformers import CLIPModel

IMAGE_MODEL = "image_encoder.onnx"
TEXT_MODEL = "text_encoder.onnx"
_COPY = (
    "config.json",
    "preprocessor_config.json",
    "tokenizer.json",
    "tokenizer_config.json",
    "special_tokens_map.json",
    "vocab.json",
    "merges.txt",
)


class _ImageTower(torch.nn.Module):
    def __init__(self, model: CLIPModel) -> None:
        super().__init__()
        self.model = model

    def forward(self, pixel_values: torch.Tensor) -> torch.Tensor:
        return _embeddings(self.model.get_image_features(pixel_values=pixel_values), "image")


class _TextTower(torch.nn.Module):
    def __init__(self, model: CLIPModel) -> None:
        super().__init__()
        self.model = model

    def forward(self, input_ids: torch.Tensor, attention_mask: torch.Tensor) -> torch.Tensor:
        out = self.model.get_text_features(input_ids=input_ids, attention_mask=attention_mask)
        return _embeddings(out, "text")


def export_clip_onnx(source: str | Path, out_dir: str | Path, *, opset: int = 17) -> Path:
    """Write ``image_encoder.onnx``, ``text_encoder.onnx`` and the tokenizer/preprocessor files."""
    from transformers import CLIPModel

    source, out_dir = Path(source), Path(out_dir)
    try:
        model = CLIPModel.from_pretrained(str(source), local_files_only=True).eval()
    except (OSError, ValueError) as exc:
        raise ModelError(f"{source}: cannot load CLIPModel ({exc})") from exc
    out_dir.mkdir(parents=True, exist_ok=True)
    size = int(model.config.vision_config.image_size)
    pixels = torch.zeros(2, 3, size, size)
    ids = torch.ones(2, 5, dtype=torch.int64)
    mask = torch.ones(2, 5, dtype=torch.int64)
    mask[1, 3:] = 0  # a padded row, so tracing keeps the padding-mask path
    with torch.no_grad(), warnings.catch_warnings():
        # Tracer and "legacy exporter" warnings are expected for this model and not actionable.
        warnings.simplefilter("ignore")
        torch.onnx.export(
            _ImageTower(model),
            (pixels,),
            str(out_dir / IMAGE_MODEL),
            input_names=["pixel_values"],
            output_names=["image_embeds"],
            dynamic_axes={"pixel_values": {0: "batch"}, "image_embeds": {0: "batch"}},
            opset_version=opset,
            dynamo=False,
        )
        torch.onnx.export(
            _TextTower(model),
            (ids, mask),
            str(out_dir / TEXT_MODEL),
            input_names=["input_ids", "attention_mask"],
            output_names=["text_embeds"],
            dynamic_axes={
                "input_ids": {0: "batch", 1: "length"},
                "attention_mask": {0: "batch", 1: "length"},
                "text_embeds": {0: "batch"},
            },
            opset_version=opset,
            dynamo=False,
        )
    for name in _COPY:
        if (source / name).is_file():
            shutil.copy2(source / name, out_dir / name)
    return out_dir
