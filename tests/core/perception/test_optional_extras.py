"""FastSAM / open_clip extras: clear errors when missing, and FastSAM's mask-to-label conversion."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from bayesian_fields_core.errors import ModelError
from bayesian_fields_core.perception.fastsam import FastSAMSegmenter, fastsam_masks_to_labels, unletterbox
from bayesian_fields_core.perception.open_clip_encoder import OpenClipEncoder


@pytest.mark.skipif(importlib.util.find_spec("ultralytics") is not None, reason="ultralytics installed")
def test_fastsam_without_extra_says_what_to_install(tmp_path: Path) -> None:
    weights = tmp_path / "FastSAM-s.pt"
    weights.write_bytes(b"\0")
    with pytest.raises(ModelError, match=r"install the 'fastsam' extra"):
        FastSAMSegmenter(weights)


@pytest.mark.skipif(importlib.util.find_spec("open_clip") is not None, reason="open_clip installed")
def test_open_clip_without_extra_says_what_to_install(tmp_path: Path) -> None:
    with pytest.raises(ModelError, match=r"install the 'open_clip' extra"):
        OpenClipEncoder("ViT-B-16", tmp_path / "ckpt.bin")


def test_fastsam_full_resolution_masks() -> None:
    masks = np.zeros((3, 20, 30), dtype=bool)
    masks[0] = True  # background-like mask
    masks[1, 2:10, 2:12] = True
    masks[2, 4:6, 4:6] = True  # 4 px < min_area: dropped before painting
    labels = fastsam_masks_to_labels(masks, (20, 30), min_area=5)
    assert labels[5, 5] == 1 and labels[0, 0] == 0 and labels.max() == 1


def test_fastsam_letterboxed_masks_are_mapped_back() -> None:
    # A 100x200 image inferred at 64x64: scaled by 0.32 to 32x64, padded 16 rows top and bottom.
    small = np.zeros((1, 64, 64), dtype=np.float32)
    small[0, 16:32, 0:32] = 1.0  # the top-left quarter of the image
    assert unletterbox(small, 100, 200).shape == (1, 32, 64)
    labels = fastsam_masks_to_labels(small, (100, 200), min_area=10)
    assert labels.shape == (100, 200)
    assert (labels[5:45, 5:95] == 0).all() and (labels[55:, :] == -1).all() and (labels[:, 105:] == -1).all()
