"""Paired task bootstrap of metric differences."""

from __future__ import annotations

import pytest

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.eval.bootstrap import paired_differences, score_intervals
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


def _scenes(strict: list[list[int]]) -> tuple[ClioScores, dict[str, str]]:
    """One GT object per task; `strict[s]` the strict counts of scene s's tasks."""
    flat = [v for scene in strict for v in scene]
    scores = _scores(flat, [0.5 * v for v in flat], [1] * len(flat))
    names = [f"scene{s}" for s, scene in enumerate(strict) for _ in scene]
    return scores, {f"t{i}": name for i, name in enumerate(names)}


def test_scenes_whose_tasks_move_together_widen_the_interval() -> None:
    # Each scene's five tasks all gain or all lose together (one shared clustering).
    a, groups = _scenes([[1] * 5, [0] * 5, [1] * 5, [0] * 5, [1] * 5, [0] * 5])
    b, _ = _scenes([[0] * 5] * 6)
    by_task = paired_differences(a, b, seed=3)
    by_scene = paired_differences(a, b, seed=3, groups=groups)
    assert by_scene["strict_osr"].mean == by_task["strict_osr"].mean == pytest.approx(0.5)
    width = {k: d["strict_osr"].high - d["strict_osr"].low for k, d in (("t", by_task), ("s", by_scene))}
    assert width["s"] > 1.5 * width["t"]
    assert paired_differences(a, b, seed=3, groups=groups) == by_scene  # seeded: deterministic


def test_scenes_alike_in_composition_narrow_the_interval() -> None:
    # Every scene has the same mix (two gains, three ties): resampling scenes changes nothing.
    a, groups = _scenes([[1, 1, 0, 0, 0]] * 6)
    b, _ = _scenes([[0] * 5] * 6)
    by_task = paired_differences(a, b)["strict_osr"]
    by_scene = paired_differences(a, b, groups=groups)["strict_osr"]
    assert (by_scene.low, by_scene.high) == pytest.approx((0.4, 0.4))
    assert by_task.high - by_task.low > 0.2
    interval = score_intervals(a, groups=groups)["strict_osr"]
    assert (interval.low, interval.value, interval.high) == pytest.approx((0.4, 0.4, 0.4))


def test_a_task_without_a_scene_is_refused() -> None:
    a, groups = _scenes([[1, 0], [0, 1]])
    del groups["t3"]
    with pytest.raises(InputError, match="no group"):
        paired_differences(a, a, groups=groups)


def test_the_suite_prints_task_and_scene_intervals_side_by_side(capsys: pytest.CaptureFixture[str]) -> None:
    from bayesian_fields_core.eval.suite import AVERAGING, FULL, print_intervals

    full, groups = _scenes([[1] * 4, [0] * 4, [1] * 4, [1] * 4])
    averaging, _ = _scenes([[0] * 4] * 4)
    print_intervals({FULL: full, AVERAGING: averaging}, groups)
    out = capsys.readouterr().out
    assert "bootstrap over the 16 tasks" in out and "bootstrap over the 4 scenes" in out
    line = next(x for x in out.splitlines() if x.strip().startswith(f"{FULL} - {AVERAGING.strip()}"))
    by_task, by_scene = line.split("tasks:")[1].split("| scenes:")
    assert by_task.strip().startswith("strict +0.750") and by_scene.strip().startswith("strict +0.750")
    assert str(paired_differences(full, averaging, groups=groups)["strict_osr"]) in by_scene


def test_relaxed_is_paired_when_asked() -> None:
    """`metrics` adds Relaxed-osR (the dial's sweep): its point value by hand, Strict unchanged."""
    gt = [2, 2, 2]
    a, b = _scores([1, 2, 2], [0.5, 1.0, 1.0], gt), _scores([1, 1, 0], [0.5, 0.5, 0.0], gt)
    a.per_task["t0"] = TaskScores(num_gt=2, strict=1, relaxed=2, iou_sum=0.5)
    diff = paired_differences(a, b, metrics=("strict_osr", "relaxed_osr"))
    assert set(diff) == {"strict_osr", "relaxed_osr"}
    assert diff["strict_osr"].mean == pytest.approx(3 / 6)
    assert diff["relaxed_osr"].mean == pytest.approx(4 / 6)
    assert set(paired_differences(a, b)) == {"strict_osr", "iou"}
