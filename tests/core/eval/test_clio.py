"""Clio metrics on hand-built maps whose IoUs and centroid tests are computed by hand."""

from __future__ import annotations

import numpy as np
import pytest

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.eval.clio import (
    ClioScores,
    EstimatedObject,
    GTObject,
    _match,
    clio_metrics,
    format_table,
    load_clio_ground_truth,
    top_k_for_task,
)
from bayesian_fields_core.geometry.obb import OrientedBox

EYE = np.eye(3)


def box(center, extents):
    return OrientedBox(center, EYE, extents)


GT = [
    GTObject("get soap", box([0, 0, 0], [2, 2, 2])),
    GTObject("get soap", box([10, 0, 0], [2, 2, 2])),
    GTObject("read book", box([0, 10, 0], [2, 2, 2])),
]
ESTIMATES = [
    # overlaps GT 0 by 1.5 along x: IoU 6 / 10; each contains the other's centre -> strict
    EstimatedObject(box([0.5, 0, 0], [2, 2, 2]), {"get soap": 0.9, "read book": 0.05}),
    # x in [9.5, 13.5] vs [9, 11]: IoU 6 / 18; contains GT 1's centre, not vice versa -> relaxed
    EstimatedObject(box([11.5, 0, 0], [4, 2, 2]), {"get soap": 0.8, "read book": 0.05}),
    # inside GT 2 but off its centre: IoU 0.125 / 8; only GT contains its centre -> relaxed (either)
    EstimatedObject(box([0.6, 10, 0], [0.5, 0.5, 0.5]), {"get soap": 0.1, "read book": 0.7}),
    # a distractor, never in the top-k
    EstimatedObject(box([50, 50, 50], [1, 1, 1]), {"get soap": 0.5, "read book": 0.6}),
]


def test_hand_computed_scores():
    s = clio_metrics(ESTIMATES, GT)
    assert s.num_gt == 3 and s.num_objects == 4
    assert s.strict_osr == pytest.approx(1 / 3)
    assert s.relaxed_osr == pytest.approx(1.0)
    assert s.iou == pytest.approx((0.6 + 1 / 3 + 1 / 64) / 3)
    assert s.per_task["get soap"].strict == 1 and s.per_task["get soap"].relaxed == 2
    assert s.per_task["read book"].iou_sum == pytest.approx(1 / 64)


def test_clio_code_relaxed_rule_needs_the_estimate_to_contain_the_gt_centroid():
    s = clio_metrics(ESTIMATES, GT, relaxed="estimate_contains_gt")
    assert s.relaxed_osr == pytest.approx(2 / 3)
    assert s.strict_osr == pytest.approx(1 / 3)


def test_only_top_k_are_queried_and_missing_objects_score_zero():
    # only one object in the map: the second soap GT is unmatched, the book task gets the same
    # (far away) object -> IoU 0, no detection
    s = clio_metrics(ESTIMATES[:1], GT, num_objects=37)
    assert s.num_objects == 37
    assert s.strict_osr == pytest.approx(1 / 3)
    assert s.iou == pytest.approx(0.6 / 3)
    assert top_k_for_task(ESTIMATES, "read book", 2) == [2, 3]
    assert top_k_for_task(ESTIMATES, "get soap", 10) == [0, 1, 3, 2]


def test_greedy_and_hungarian_matching_differ_as_documented():
    iou = np.array([[0.5, 0.4], [0.4, 0.0]])
    assert _match(iou, "greedy") == [(0, 0)]  # then only a zero pair remains
    assert sorted(_match(iou, "hungarian")) == [(0, 1), (1, 0)]
    assert _match(np.zeros((2, 2)), "hungarian") == []


def test_dict_inputs_and_errors():
    ests = [{"box": e.box.to_dict(), "probabilities": e.probabilities} for e in ESTIMATES]
    gts = [{"task": g.task, "box": g.box.to_dict()} for g in GT]
    assert clio_metrics(ests, gts).relaxed_osr == pytest.approx(1.0)
    with pytest.raises(InputError, match="no ground-truth"):
        clio_metrics(ests, [])
    with pytest.raises(InputError, match="probabilities"):
        clio_metrics([{"box": ESTIMATES[0].box.to_dict()}], gts)


def test_load_clio_ground_truth_quaternions():
    c, s = np.cos(np.pi / 4), np.sin(np.pi / 4)
    data = {
        "get soap": [
            {"center": [1, 2, 3], "extents": [4, 2, 1], "rotation": {"w": c, "x": 0, "y": 0, "z": s}}
        ],
        "read book": [{"center": [0, 0, 0], "extents": [1, 1, 1], "rotation": [1, 0, 0, 0]}],
    }
    gts = load_clio_ground_truth(data)
    assert [g.task for g in gts] == ["get soap", "read book"]
    # 90 degrees about z: the first box axis points along world y
    np.testing.assert_allclose(gts[0].box.rotation[:, 0], [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(gts[1].box.rotation, EYE)
    with pytest.raises(InputError, match="missing field 'extents'"):
        load_clio_ground_truth({"t": [{"center": [0, 0, 0], "rotation": [1, 0, 0, 0]}]}, source="gt.yaml")


def test_format_table_plain_and_markdown():
    rows = {
        "Bayesian Fields": ClioScores(0.891, 0.9449, 0.2612, 37, 18, time_s=480.0),
        "Clio-batch": ClioScores(0.83, 1.0, 0.17, 48, 18),
    }
    text = format_table(rows)
    lines = text.splitlines()
    assert lines[0].split() == ["Method", "Strict-osR", "Relaxed-osR", "IoU", "Objs", "Time", "(min)"]
    assert lines[2].split() == ["Bayesian", "Fields", "0.89", "0.94", "0.26", "37", "8.0"]
    assert lines[3].split()[-1] == "-"
    md = format_table(rows, markdown=True, show_time=False)
    assert md.splitlines()[0] == "| Method | Strict-osR | Relaxed-osR | IoU | Objs |"
    assert md.splitlines()[3] == "| Clio-batch | 0.83 | 1.00 | 0.17 | 48 |"
