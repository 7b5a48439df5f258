"""Causes of missed GT objects (eval/breakdown.py) and Table 1's per-row intervals."""

from __future__ import annotations

import numpy as np

from bayesian_fields_core.eval.bootstrap import score_intervals
from bayesian_fields_core.eval.breakdown import (
    SceneInstance,
    TaskBreakdown,
    classify_task,
    format_breakdown,
    task_breakdowns,
)
from bayesian_fields_core.eval.clio import ClioScores, EstimatedObject, GTObject, TaskScores
from bayesian_fields_core.eval.tables import format_interval_table
from bayesian_fields_core.geometry.obb import OrientedBox


def _box(x: float, y: float = 0.0, size: float = 0.1) -> OrientedBox:
    return OrientedBox(np.array([x, y, 0.05]), np.eye(3), np.full(3, size))


MUG, NEIGHBOUR, FAR = _box(0.0), _box(0.15), _box(1.0)
INSTANCES = [SceneInstance("red mug", MUG), SceneInstance("green mug", NEIGHBOUR), SceneInstance("x", FAR)]


def test_each_cause_is_recognised() -> None:
    assert classify_task("t", [MUG], [_box(0.0, size=0.11)], INSTANCES) == ["ok"]
    # One box around the mug and its neighbour: under-segmentation.
    merged = OrientedBox(np.array([0.075, 0.0, 0.05]), np.eye(3), np.array([0.3, 0.12, 0.12]))
    assert classify_task("t", [MUG], [merged], INSTANCES) == ["merged"]
    # A fragment of the mug: over-segmentation.
    fragment = OrientedBox(np.array([0.03, 0.0, 0.05]), np.eye(3), np.array([0.04, 0.1, 0.1]))
    assert classify_task("t", [MUG], [fragment], INSTANCES) == ["split"]
    # Answered with another object entirely.
    assert classify_task("t", [MUG], [FAR], INSTANCES) == ["wrong instance"]
    assert classify_task("t", [MUG, NEIGHBOUR], [], INSTANCES) == ["missed", "missed"]


def test_task_breakdowns_use_the_top_k_answers_and_group_families() -> None:
    estimates = [
        EstimatedObject(_box(0.0), {"get the red mug": 1.0, "get the red mug with the blue label": 0.5}),
        EstimatedObject(FAR, {"get the red mug with the blue label": 1.0}),
    ]
    gt = [GTObject("get the red mug", MUG), GTObject("get the red mug with the blue label", MUG)]
    tasks = ["get the red mug", "get the red mug with the blue label", "get the cyan cone"]
    rows = task_breakdowns("s", tasks, estimates, gt, INSTANCES)
    assert [(r.kind, r.causes) for r in rows] == [("fine", ["ok"]), ("label", ["wrong instance"])]
    text = format_breakdown(rows + [TaskBreakdown("s", "move all the red things", ["split", "ok"])])
    last = text.splitlines()[-1].split()
    assert last[:3] == ["all", "tasks", "4"] and last[3] == "2"  # GT 4, ok 2


def test_score_intervals_bracket_the_pooled_value_and_shrink_with_agreement() -> None:
    def scores(strict: list[int]) -> ClioScores:
        per = {
            f"t{i}": TaskScores(num_gt=1, strict=s, relaxed=1, iou_sum=0.5 * s) for i, s in enumerate(strict)
        }
        n = len(strict)
        return ClioScores(sum(strict) / n, 1.0, 0.5 * sum(strict) / n, 10, n, per)

    mixed = score_intervals(scores([1, 0] * 20))
    assert mixed["strict_osr"].low < 0.5 < mixed["strict_osr"].high
    assert mixed["strict_osr"].value == 0.5 and mixed["relaxed_osr"].low == mixed["relaxed_osr"].high == 1.0
    assert score_intervals(scores([1] * 40))["strict_osr"].low == 1.0
    table = format_interval_table({"full": mixed})
    assert "0.50 [" in table and "1.00 [1.00, 1.00]" in table


def test_eval_command_selects_the_suite_by_name() -> None:
    import pytest

    from bayesian_fields_core.cli.main import build_parser

    args = build_parser().parse_args(["eval", "--suite", "capture", "--breakdown", "--seeds", "7,8,9"])
    assert (args.suite, args.breakdown, args.seeds) == ("capture", True, [7, 8, 9])
    assert build_parser().parse_args(["eval"]).suite == "tabletop"
    with pytest.raises(SystemExit):
        build_parser().parse_args(["eval", "--suite", "kitchen"])
