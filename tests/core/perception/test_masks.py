"""exclusive_labels / label_boxes: the smallest covering mask wins, small masks are dropped."""

from __future__ import annotations

import numpy as np
import pytest

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.perception.masks import (
    exclusive_assignment,
    exclusive_labels,
    filter_small_labels,
    label_boxes,
)


def _box_mask(h: int, w: int, y0: int, x0: int, y1: int, x1: int) -> np.ndarray:
    m = np.zeros((h, w), dtype=bool)
    m[y0:y1, x0:x1] = True
    return m


def test_smallest_covering_mask_wins_and_order_kept() -> None:
    table = _box_mask(20, 30, 0, 0, 20, 30)  # area 600
    cup = _box_mask(20, 30, 5, 5, 10, 10)  # area 25, inside the table
    plate = _box_mask(20, 30, 4, 4, 12, 12)  # area 64, contains the cup
    labels = exclusive_labels(np.stack([table, cup, plate]), min_area=0)
    assert labels.dtype == np.int32 and labels.shape == (20, 30)
    assert (labels[5:10, 5:10] == 1).all()  # cup beats plate and table
    assert labels[4, 4] == 2 and labels[11, 11] == 2  # plate ring
    assert labels[0, 0] == 0 and labels[19, 29] == 0
    assert np.bincount(labels.ravel()).tolist() == [600 - 64, 25, 64 - 25]


def test_min_area_drops_specks_before_and_after_painting() -> None:
    big = _box_mask(10, 10, 0, 0, 10, 10)
    speck = _box_mask(10, 10, 0, 0, 2, 2)  # area 4 < 5: dropped before painting
    mid = _box_mask(10, 10, 5, 5, 10, 10)  # area 25
    hidden = _box_mask(10, 10, 5, 5, 10, 10) | _box_mask(10, 10, 4, 4, 5, 5)  # 26, but only 1 px left
    labels, source = exclusive_assignment(np.stack([big, speck, mid, hidden]), min_area=5)
    assert source.tolist() == [0, 2]
    assert labels[0, 0] == 0  # the speck did not steal the big mask's pixels
    assert labels[4, 4] == -1  # the hidden mask's only own pixel is dropped with it
    assert (labels[5:, 5:] == 1).all()
    assert set(np.unique(labels).tolist()) == {-1, 0, 1}


def test_ties_and_empty_inputs() -> None:
    a = _box_mask(4, 4, 0, 0, 2, 2)
    labels = exclusive_labels(np.stack([a, a.copy()]))
    assert (labels[:2, :2] == 0).all() and labels.max() == 0
    empty = exclusive_labels(np.zeros((0, 3, 5), dtype=bool))
    assert empty.shape == (3, 5) and (empty == -1).all()
    with pytest.raises(InputError, match="masks"):
        exclusive_labels(np.zeros((3, 5), dtype=bool))


def test_matches_reference_painting_on_random_masks() -> None:
    rng = np.random.default_rng(0)
    masks = rng.random((12, 40, 50)) < rng.uniform(0.02, 0.6, size=(12, 1, 1))
    labels, source = exclusive_assignment(masks, min_area=0)
    # Reference: paint largest-first (stable, so equal areas paint in index order, lower index last).
    areas = masks.sum((1, 2))
    ref = np.full((40, 50), -1)
    order = sorted(range(12), key=lambda i: (-areas[i], -i))
    for i in order:
        ref[masks[i]] = i
    got = np.where(labels >= 0, source[np.maximum(labels, 0)], -1)
    assert np.array_equal(got, ref)


def test_filter_small_labels_renumbers() -> None:
    raw = np.array([[0, 0, 1], [2, 2, 2], [3, -1, 2]])
    out = filter_small_labels(raw, min_area=2)
    assert out.tolist() == [[0, 0, -1], [1, 1, 1], [-1, -1, 1]]
    assert filter_small_labels(np.full((2, 2), -1), 1).tolist() == [[-1, -1], [-1, -1]]


def test_label_boxes_and_areas() -> None:
    labels = np.full((6, 8), -1, dtype=np.int32)
    labels[1:3, 2:5] = 0
    labels[4:6, 0:1] = 2
    boxes, areas = label_boxes(labels)
    assert boxes.tolist() == [[2, 1, 5, 3], [0, 0, 0, 0], [0, 4, 1, 6]]
    assert areas.tolist() == [6, 0, 2]
    boxes, areas = label_boxes(np.full((3, 3), -1), num_labels=0)
    assert boxes.shape == (0, 4) and areas.shape == (0,)
