"""ClassicalSegmenter on synthetic images with known regions."""

from __future__ import annotations

import numpy as np
import pytest

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.perception.classical import ClassicalSegmenter, upsample_labels_nearest
from bayesian_fields_core.perception.segmenter import Segmenter


def _quadrants(h: int = 96, w: int = 128) -> np.ndarray:
    img = np.zeros((h, w, 3), dtype=np.uint8)
    img[: h // 2, : w // 2] = (230, 20, 20)
    img[: h // 2, w // 2 :] = (20, 230, 20)
    img[h // 2 :, : w // 2] = (20, 20, 230)
    img[h // 2 :, w // 2 :] = (230, 230, 20)
    return img


@pytest.mark.parametrize("method", ["felzenszwalb", "slic"])
def test_segments_follow_colour_regions(method: str) -> None:
    img = _quadrants()
    seg = ClassicalSegmenter(
        method, scale=50, sigma=0.0, n_segments=4, compactness=1.0, min_area=16, max_side=None
    )
    assert isinstance(seg, Segmenter)
    labels = seg.segment(img)
    assert labels.shape == img.shape[:2] and labels.dtype == np.int32
    ids = np.unique(labels)
    assert ids.min() >= 0 and ids.tolist() == list(range(ids.size))
    # No label crosses a colour boundary.
    colour_id = img[..., 0].astype(int) * 7 + img[..., 1].astype(int) * 3 + img[..., 2]
    for lab in ids:
        assert np.unique(colour_id[labels == lab]).size == 1
    if method == "felzenszwalb":
        assert ids.size == 4


def test_downscale_then_nearest_upsample_keeps_regions_and_min_area() -> None:
    img = _quadrants(400, 600)
    img[10:14, 10:14] = (255, 255, 255)  # a 16 px speck, below min_area at full resolution
    seg = ClassicalSegmenter(scale=50, sigma=0.0, min_size=30, min_area=200, max_side=150)
    labels = seg.segment(img)
    assert labels.shape == (400, 600)
    assert np.unique(labels[labels >= 0]).size == 4
    assert labels[11, 11] == -1 or np.count_nonzero(labels == labels[11, 11]) >= 200
    assert seg.params["max_side"] == 150 and seg.params["scale"] == 50


def test_upsample_labels_nearest() -> None:
    small = np.array([[0, 1], [2, 3]])
    big = upsample_labels_nearest(small, 4, 6)
    assert big[:2, :3].tolist() == [[0, 0, 0], [0, 0, 0]] and big[3, 5] == 3


def test_bad_input() -> None:
    seg = ClassicalSegmenter()
    with pytest.raises(InputError, match="uint8"):
        seg.segment(np.zeros((4, 4, 3), dtype=np.float32))
    with pytest.raises(InputError, match="method"):
        ClassicalSegmenter("watershed")  # type: ignore[arg-type]
