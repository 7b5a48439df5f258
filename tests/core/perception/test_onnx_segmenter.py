"""OnnxSegmenter with a real ONNX model exported from a tiny torch module (colour thresholds)."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
import torch

from bayesian_fields_core.errors import InputError, ModelError
from bayesian_fields_core.perception.onnx_segmenter import OnnxSegmenter
from bayesian_fields_core.perception.segmenter import Segmenter


class ColourMasks(torch.nn.Module):
    """4 masks: red, green, blue dominant, and 'any saturated colour' (covers all three);
    scores = 0.9, 0.9, 0.2, 0.8. Outputs logits or probabilities at half resolution."""

    def __init__(self, logits: bool) -> None:
        super().__init__()
        self.logits = logits

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        r, g, b = x[:, 0], x[:, 1], x[:, 2]
        raw = torch.stack([r - (g + b) / 2, g - (r + b) / 2, b - (r + g) / 2], dim=1)
        raw = torch.cat([raw, raw.amax(dim=1, keepdim=True)], dim=1) - 0.25
        raw = torch.nn.functional.avg_pool2d(raw, 2)
        out = raw * 40.0 if self.logits else (raw > 0).float()
        scores = torch.tensor([[0.9, 0.9, 0.2, 0.8]]).expand(x.shape[0], 4)
        return out, scores


def _export(tmp_path: Path, logits: bool) -> Path:
    path = tmp_path / f"colours_{'logits' if logits else 'probs'}.onnx"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(
            ColourMasks(logits),
            (torch.zeros(1, 3, 64, 64),),
            str(path),
            input_names=["image"],
            output_names=["masks", "scores"],
            opset_version=17,
            dynamo=False,
        )
    return path


@pytest.mark.parametrize("logits", [False, True])
@pytest.mark.slow
def test_segments_colour_regions_smallest_wins(tmp_path: Path, scene_image: np.ndarray, logits: bool) -> None:
    seg = OnnxSegmenter(
        _export(tmp_path, logits), mask_output="logits" if logits else "probabilities", min_area=20
    )
    assert isinstance(seg, Segmenter) and seg.input_size == (64, 64)
    labels = seg.segment(scene_image)
    assert labels.shape == (60, 80) and labels.dtype == np.int32
    # Each coloured rectangle is its own (smallest) mask, not the covering "any colour" mask.
    red, green, blue = labels[15, 20], labels[42, 20], labels[30, 60]
    assert len({int(red), int(green), int(blue)}) == 3 and min(red, green, blue) >= 0
    assert (labels[8:22, 8:32] == red).all() and (labels[33:52, 13:27] == green).all()
    assert (labels[13:47, 48:72] == blue).all()
    assert labels[0, 0] == -1 and labels[58, 40] == -1  # gray background: no mask


def test_score_threshold_drops_low_scoring_masks(tmp_path: Path, scene_image: np.ndarray) -> None:
    seg = OnnxSegmenter(_export(tmp_path, False), score_threshold=0.5, min_area=20)
    labels = seg.segment(scene_image)
    # Blue (score 0.2) is gone; its pixels fall back to the covering "any colour" mask.
    assert labels[30, 60] >= 0 and labels[30, 60] != labels[15, 20]
    assert np.unique(labels[labels >= 0]).size == 3
    assert seg.params["score_threshold"] == 0.5


def test_errors(tmp_path: Path) -> None:
    with pytest.raises(ModelError, match="not found"):
        OnnxSegmenter(tmp_path / "missing.onnx")
    with pytest.raises(InputError, match="mask_output"):
        OnnxSegmenter(tmp_path / "missing.onnx", mask_output="masks")  # type: ignore[arg-type]
    seg = OnnxSegmenter(_export(tmp_path, False), input_size=64)
    with pytest.raises(InputError, match="image"):
        seg.segment(np.zeros((10, 10), dtype=np.uint8))
