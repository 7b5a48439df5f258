"""LeRF protocol: the 0.8 x best object set, mask IoU, accuracy at 0.25, and the scene mean."""

from __future__ import annotations

import numpy as np
import pytest

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.eval.lerf import (
    LerfScores,
    format_lerf_table,
    lerf_scores,
    mask_iou,
    mean_over_scenes,
    query_iou,
    query_mask,
    select_objects,
)


def test_object_set_is_within_ratio_of_the_best():
    p = np.array([0.5, 0.9, 0.73, 0.71, 0.1])
    np.testing.assert_array_equal(select_objects(p), [1, 2])  # 0.8 * 0.9 = 0.72: 0.73 in, 0.71 out
    np.testing.assert_array_equal(select_objects(p, ratio=0.5), [0, 1, 2, 3])
    with pytest.raises(InputError):
        select_objects(p, ratio=0.0)


def test_query_iou_by_hand():
    ids = np.array(
        [
            [-1, 0, 0, 1],
            [-1, 0, 2, 1],
            [3, 3, 2, 2],
        ]
    )
    gt = np.zeros_like(ids, dtype=bool)
    gt[0, 1:3] = True
    gt[1, 1] = True
    gt[1, 2] = True
    # objects 0 and 2 are selected (0.9, 0.8 >= 0.72); object 1 (0.5) is not
    probs = np.array([0.9, 0.5, 0.8, 0.1])
    mask = query_mask(ids, select_objects(probs))
    assert mask.sum() == 6  # three 0s and three 2s
    assert query_iou(probs, ids, gt) == pytest.approx(4 / 6)
    assert mask_iou(gt, gt) == 1.0
    with pytest.raises(InputError, match="empty"):
        mask_iou(gt, np.zeros_like(gt))
    with pytest.raises(InputError, match="shape"):
        mask_iou(gt, gt[:2])


def test_scores_and_paper_mean():
    s = lerf_scores([0.5, 0.25, 0.1, 0.9])
    assert s.miou == pytest.approx(0.4375)
    assert s.macc == pytest.approx(0.5)  # 0.25 is not > 0.25
    # the paper's Table 3 row: per-scene figures average to 39.29 / 59.67
    paper = {
        "figurines": LerfScores(0.4670, 0.6786, 1),
        "teatime": LerfScores(0.5276, 0.7119, 1),
        "ramen": LerfScores(0.2912, 0.4507, 1),
        "kitchen": LerfScores(0.2857, 0.5455, 1),
    }
    miou, macc = mean_over_scenes(paper).as_percent()
    assert round(miou, 2) == 39.29 and round(macc, 2) == 59.67
    table = format_lerf_table({"ours": paper}, markdown=True)
    assert table.splitlines()[2].endswith("| 39.29 / 59.67 |")
    with pytest.raises(InputError):
        lerf_scores([])
