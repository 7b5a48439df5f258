"""The "not found" shares with scene-level intervals: counts by hand, and the interval's width
following how the misses are spread over scenes."""

from __future__ import annotations

import pytest

from bayesian_fields_core.eval.not_found_intervals import format_shares, not_found_shares
from bayesian_fields_core.eval.not_found_tradeoff import TaskOutcome


def _scene(name: str, absent: list[float | None], present: list[float | None]) -> list[TaskOutcome]:
    return [TaskOutcome(f"a{i}", True, s, scene=name) for i, s in enumerate(absent)] + [
        TaskOutcome(f"p{i}", False, s, num_gt=1, strict=1, relaxed=1, scene=name)
        for i, s in enumerate(present)
    ]


def test_the_shares_count_by_hand() -> None:
    outcomes = _scene("s1", [0.2, None], [0.9, 1.1]) + _scene("s2", [0.95], [0.5, 1.2, 1.3])
    shares = not_found_shares(outcomes, 0.8)
    # absent: 0.2 < 0.8 and None (no candidate) are "not found", 0.95 is answered
    assert (shares.absent_not_found.hits, shares.absent_not_found.total) == (2, 3)
    # present: 0.5 < 0.8 is lost
    assert (shares.present_lost.hits, shares.present_lost.total) == (1, 5)
    assert (shares.present_lost_to_threshold.hits, shares.present_lost_to_threshold.total) == (1, 5)
    unanswered = not_found_shares([*outcomes, *_scene("s3", [], [None])], 0.8)  # no candidate at all
    assert (unanswered.present_lost.hits, unanswered.present_lost.total) == (2, 6)
    assert (unanswered.present_lost_to_threshold.hits, unanswered.present_lost_to_threshold.total) == (1, 5)
    assert shares.scenes == 2
    assert shares.absent_not_found.low <= 2 / 3 <= shares.absent_not_found.high
    off = not_found_shares(outcomes, None)  # rule off: only the task without a candidate
    assert (off.absent_not_found.hits, off.present_lost.hits) == (1, 0)
    line = format_shares(shares, "at")
    assert "2/3 = 66.7%" in line and "1/5 = 20.0%" in line and "2 scenes" in line


def test_the_interval_resamples_scenes() -> None:
    # every scene alike: any draw gives the same shares, so the interval is a point
    alike = [o for i in range(10) for o in _scene(f"s{i}", [0.1], [1.0, 1.0, 1.0])]
    shares = not_found_shares(alike, 0.5)
    assert shares.absent_not_found.value == 1.0
    assert (shares.absent_not_found.low, shares.absent_not_found.high) == (1.0, 1.0)
    assert (shares.present_lost.low, shares.present_lost.high) == (0.0, 0.0)
    # one scene holds every miss: a draw without it catches all, one with it twice catches less
    clustered = [o for i in range(9) for o in _scene(f"s{i}", [0.1], [1.0])] + _scene("bad", [0.9] * 3, [1.0])
    shares = not_found_shares(clustered, 0.5)
    assert shares.absent_not_found.value == pytest.approx(9 / 12)
    assert shares.absent_not_found.high == 1.0 and shares.absent_not_found.low < 0.6
    assert not_found_shares(clustered, 0.5) == shares  # seeded: the same interval every time


def test_no_outcomes_give_no_share() -> None:
    shares = not_found_shares([], 0.5)
    assert shares.scenes == 0 and str(shares.absent_not_found) == "-"
