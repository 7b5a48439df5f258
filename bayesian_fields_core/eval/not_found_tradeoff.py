"""How the "not found" rule (`objects.not_found`) trades absent tasks against present ones.

Table 1 is scored as the paper scores it, every task answered (the evaluation runs the pipeline
with the rule off). Each task's best candidate keeps its rule score, so the rule at any threshold
is applied afterwards with the same function the pipeline uses (`objects.not_found.is_not_found`):
- **absent → not found**: the share of tasks without a GT object that the rule leaves unanswered
  (what we want: a robot should not act on a confident answer to "pick up the red lamp");
- **recall lost**: the share of the present tasks' correct detections (Relaxed-osR matches) that
  the rule throws away by leaving their task unanswered; `strict lost` the same for Strict-osR.
Sweeping the threshold gives the trade-off curve (`tradeoff_curve`, `bfields eval
--not-found-curve`) that the default `answer_min_peak` is chosen on.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from bayesian_fields_core.eval.clio import ClioScores
from bayesian_fields_core.eval.tables import render_table
from bayesian_fields_core.objects.not_found import is_not_found


@dataclass(frozen=True)
class TaskOutcome:
    """One task of one scene as a row answered it: `score` is its best candidate's rule score
    (None: no candidate, always "not found"); detections count its GT objects found."""

    task: str
    absent: bool
    score: float | None
    num_gt: int = 0
    strict: int = 0
    relaxed: int = 0
    scene: str = ""  # the resampling unit of the shares' intervals (`not_found_intervals.py`)


@dataclass(frozen=True)
class NotFoundStats:
    """The rule at `threshold` over a set of task outcomes."""

    threshold: float | None
    absent: int
    absent_not_found: int
    present: int
    present_not_found: int
    relaxed: int
    relaxed_lost: int
    strict: int
    strict_lost: int

    @property
    def absent_share(self) -> float:
        """Share of absent tasks answered "not found" (1.0 when there is none to answer)."""
        return self.absent_not_found / self.absent if self.absent else 1.0

    @property
    def recall_lost(self) -> float:
        """Share of the present tasks' Relaxed-osR detections lost to "not found" answers."""
        return self.relaxed_lost / self.relaxed if self.relaxed else 0.0

    @property
    def strict_recall_lost(self) -> float:
        return self.strict_lost / self.strict if self.strict else 0.0


def task_outcomes(
    tasks: Sequence[str], scores: ClioScores, best_scores: Mapping[str, float | None], scene: str = ""
) -> list[TaskOutcome]:
    """Outcomes of every task of one scene: present ones (in `scores.per_task`) with their
    detections, the others absent. `best_scores` maps a task to its best candidate's rule score."""
    out = []
    for task in tasks:
        ts = scores.per_task.get(task)
        score = best_scores.get(task)
        if ts is None:
            out.append(TaskOutcome(task, True, score, scene=scene))
        else:
            out.append(TaskOutcome(task, False, score, ts.num_gt, ts.strict, ts.relaxed, scene=scene))
    return out


def not_found_stats(outcomes: Iterable[TaskOutcome], threshold: float | None) -> NotFoundStats:
    """Apply the rule at `threshold` to every outcome and count what it does."""
    counts = dict.fromkeys(
        ("absent", "absent_nf", "present", "present_nf", "relaxed", "relaxed_lost", "strict", "strict_lost"),
        0,
    )
    for o in outcomes:
        nf = is_not_found(o.score, threshold)
        if o.absent:
            counts["absent"] += 1
            counts["absent_nf"] += int(nf)
            continue
        counts["present"] += 1
        counts["present_nf"] += int(nf)
        counts["relaxed"] += o.relaxed
        counts["strict"] += o.strict
        if nf:
            counts["relaxed_lost"] += o.relaxed
            counts["strict_lost"] += o.strict
    return NotFoundStats(
        threshold,
        counts["absent"],
        counts["absent_nf"],
        counts["present"],
        counts["present_nf"],
        counts["relaxed"],
        counts["relaxed_lost"],
        counts["strict"],
        counts["strict_lost"],
    )


def tradeoff_curve(
    outcomes: Sequence[TaskOutcome], thresholds: Iterable[float] | None = None
) -> list[NotFoundStats]:
    """The rule's statistics at each threshold; by default at every distinct best-candidate score
    (the only places the counts change) plus one below them all (the rule never fires)."""
    if thresholds is None:
        scores = sorted({o.score for o in outcomes if o.score is not None})
        below = (scores[0] - 1.0) if scores else 0.0
        thresholds = [below, *scores]
    return [not_found_stats(outcomes, t) for t in thresholds]


def best_threshold(curve: Sequence[NotFoundStats], max_recall_lost: float = 0.05) -> NotFoundStats | None:
    """The point of the curve that answers the most absent tasks "not found" while losing at most
    `max_recall_lost` of the present detections (ties: the lowest threshold, losing least)."""
    ok = [s for s in curve if s.recall_lost <= max_recall_lost]
    if not ok:
        return None
    return max(ok, key=lambda s: (s.absent_share, -(s.threshold or 0.0)))


def _cells(stats: NotFoundStats) -> list[str]:
    return [
        f"{stats.absent_not_found}/{stats.absent} ({100 * stats.absent_share:.0f}%)" if stats.absent else "-",
        f"{stats.present_not_found}/{stats.present}",
        f"{100 * stats.recall_lost:.1f}%",
        f"{100 * stats.strict_recall_lost:.1f}%",
    ]


_HEADER = ["Absent: not found", "Present: not found", "Recall lost", "Strict lost"]


def format_not_found_table(
    rows: Mapping[str, Sequence[TaskOutcome]],
    *,
    threshold: float | None,
    markdown: bool = False,
) -> str:
    """Per Table 1 row, what the rule at `threshold` does: absent tasks answered "not found",
    present tasks answered "not found", and the share of correct detections that costs."""
    body = []
    for name, outcomes in rows.items():
        if not outcomes:
            body.append([name.strip(), "n/a", "n/a", "n/a", "n/a"])
            continue
        body.append([name.strip(), *_cells(not_found_stats(outcomes, threshold))])
    shown = "None (rule off)" if threshold is None else f"{threshold:g}"
    title = f'"Not found" answers at answer_min_peak = {shown} (rows without the rule\'s score: n/a)'
    return title + "\n" + render_table(["Method", *_HEADER], body, markdown=markdown)


def format_curve(curve: Sequence[NotFoundStats], *, markdown: bool = False, max_rows: int = 25) -> str:
    """The trade-off curve as a table (thinned to about `max_rows` points, keeping every point
    where the absent share changes)."""
    keep: list[NotFoundStats] = []
    for i, s in enumerate(curve):
        if i == 0 or i == len(curve) - 1 or s.absent_share != curve[i - 1].absent_share:
            keep.append(s)
    rest = [s for s in curve if s not in keep]
    if len(keep) < max_rows and rest:
        step = max(1, int(np.ceil(len(rest) / (max_rows - len(keep)))))
        keep += rest[::step]
    keep.sort(key=lambda s: s.threshold or 0.0)  # curve points all have one
    body = [[f"{s.threshold:.4g}", *_cells(s)] for s in keep]
    return render_table(["Threshold", *_HEADER], body, markdown=markdown)
