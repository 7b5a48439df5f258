"""mask_crops geometry/background and embed_masks with the tiny CLIP."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.perception.crops import crop_windows, embed_masks, mask_crops
from bayesian_fields_core.perception.hf_clip import HFClipEncoder


def _labels(scene_image: np.ndarray) -> np.ndarray:
    labels = np.full(scene_image.shape[:2], -1, dtype=np.int32)
    labels[5:25, 5:35] = 0  # red, 20 x 30
    labels[30:55, 10:30] = 1  # green, 25 x 20
    labels[10:50, 45:75] = 2  # blue, touches nothing
    labels[0:4, 76:80] = 3  # a corner mask: window crosses the border
    return labels


def test_square_padded_crops_with_gray_background(scene_image: np.ndarray) -> None:
    labels = _labels(scene_image)
    labels[12, 12] = -1  # a hole in the red mask shows as background
    crops = mask_crops(scene_image, labels, pad_fraction=0.1)
    assert len(crops) == 4 and all(c.dtype == np.uint8 and c.shape[0] == c.shape[1] for c in crops)
    red = crops[0]
    assert red.shape == (36, 36, 3)  # side 30 + 2 * ceil(3)
    assert (red[18, 18] == (220, 30, 30)).all()
    assert (red[0, 0] == 128).all()  # padding
    # The hole: window x0 = 20 - 18 = 2, y0 = 15 - 18 = -3 -> (12, 12) is at crop (15, 10).
    assert (red[15, 10] == 128).all() and (red[15, 11] == (220, 30, 30)).all()
    # Only the mask's colour or background in each crop, never another mask's pixels.
    for crop, colour in zip(crops[:3], [(220, 30, 30), (30, 200, 40), (40, 60, 220)], strict=True):
        px = crop.reshape(-1, 3)
        assert ((px == colour).all(1) | (px == 128).all(1)).all()
    corner = crops[3]
    assert corner.shape == (6, 6, 3) and (corner == 128).all()  # image there is gray too


def test_background_modes_and_rectangles(scene_image: np.ndarray) -> None:
    labels = _labels(scene_image)
    black = mask_crops(scene_image, labels, background="black", pad_fraction=0.0, square=False)
    assert black[0].shape == (20, 30, 3) and (black[0] == (220, 30, 30)).all()
    keep = mask_crops(scene_image, labels, background="keep", pad_fraction=0.5, square=False)
    # Green box 25 x 20 padded by ceil(12.5) = 13: window rows 17..68, cols -3..43; red pixels kept.
    assert keep[1].shape == (51, 46, 3)
    assert (keep[1][:8] == (220, 30, 30)).all(-1).any()
    assert (keep[1][-5:] == 128).all()  # below the image
    black_pad = mask_crops(scene_image, labels, background="black", pad_fraction=0.5, square=False)
    assert not (black_pad[1][:8] == (220, 30, 30)).all(-1).any() and (black_pad[1][0, 0] == 0).all()


def test_crop_windows_square_contains_box() -> None:
    boxes = np.array([[10, 20, 13, 30], [0, 0, 1, 1]])
    win = crop_windows(boxes, 0.2, True)
    sizes = win[:, 2:] - win[:, :2]
    assert (sizes[:, 0] == sizes[:, 1]).all()
    assert (win[:, :2] <= boxes[:, :2]).all() and (win[:, 2:] >= boxes[:, 2:]).all()


@pytest.mark.slow
def test_embed_masks_one_batch(tiny_clip_dir: Path, scene_image: np.ndarray) -> None:
    enc = HFClipEncoder(tiny_clip_dir)
    labels = _labels(scene_image)
    emb = embed_masks(enc, scene_image, labels)
    assert emb.shape == (4, 16)
    assert np.allclose(emb, enc.encode_images(mask_crops(scene_image, labels)), atol=1e-6)
    assert not np.allclose(emb[0], emb[1], atol=1e-3)
    empty = embed_masks(enc, scene_image, np.full((60, 80), -1, dtype=np.int32))
    assert empty.shape == (0, 16) and empty.dtype == np.float32


def test_bad_inputs(scene_image: np.ndarray) -> None:
    with pytest.raises(InputError, match="labels"):
        mask_crops(scene_image, np.zeros((5, 5), dtype=np.int32))
    with pytest.raises(InputError, match="background"):
        mask_crops(scene_image, _labels(scene_image), background="white")  # type: ignore[arg-type]
