"""Paired task bootstrap of metric differences."""

from __future__ import annotations

import pytest

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.eval.bootstrap import paired_differences
from bayesian_fields_core.eval.clio import ClioScores, TaskScores


def _scores(strict: list[int], iou: list[float], gt: list[int]) -> ClioScores:
    per_task = {
        f"t{i}": TaskScores(num_gt=g, strict=s, relaxed=s, iou_sum=u)
        for i, (s, u, g) in enumerate(zip(strict, iou, gt, strict=True))
    }
    total = sum(gt)
    return ClioScores(sum(strict) / total, sum(strict) / total, sum(iou) / total, 10, total, per_task)


def test_point_estimates_by_hand_and_identical_rows_give_zero() -> None:
    a = _scores([1, 1, 0, 2], [0.5, 0.4, 0.0, 1.2], [1, 1, 1, 2])
    b = _scores([0, 1, 0, 1], [0.1, 0.4, 0.0, 0.5], [1, 1, 1, 2])
    diff = paired_differences(a, b)
    assert diff["strict_osr"].mean == pytest.approx((4 - 2) / 5)
    assert diff["iou"].mean == pytest.approx((2.1 - 1.0) / 5)
    assert diff["strict_osr"].low <= diff["strict_osr"].mean <= diff["strict_osr"].high
    same = paired_differences(a, a)
    assert (same["strict_osr"].low, same["strict_osr"].high) == (0.0, 0.0)
    assert not same["strict_osr"].significant


def test_a_consistent_gain_is_significant_and_a_single_task_is_not() -> None:
    many = 40
    better = _scores([1] * many, [0.6] * many, [1] * many)
    worse = _scores([0] * many, [0.2] * many, [1] * many)
    assert paired_differences(better, worse)["strict_osr"].significant
    # One task out of 40 differs: the interval reaches 0.
    almost = _scores([1] * (many - 1) + [0], [0.6] * many, [1] * many)
    assert not paired_differences(better, almost)["strict_osr"].significant


def test_rows_on_different_tasks_are_refused() -> None:
    a = _scores([1, 0], [0.5, 0.0], [1, 1])
    b = _scores([1], [0.5], [1])
    with pytest.raises(InputError, match="different tasks"):
        paired_differences(a, b)
