"""Paired bootstrap of Table 1's differences: is a row really better than another, or is the gap
within what resampling the tasks (or the scenes) would give?

The suite has tens of tasks and under a hundred (task, GT object) pairs, so a gap of one or two
detections moves Strict-osR by a few hundredths. Resampling whole tasks (with replacement, the
same draw for both rows, since both answered the same tasks) gives a percentile interval of the
difference in Strict-osR and IoU; an interval that contains 0 means the suite cannot tell the rows
apart.

Tasks of one scene are not independent: they share one clustering, so one bad merge moves several
of them together (issue 33). With `groups` (task key -> scene) the resampling unit is the scene:
a drawn scene brings all its tasks, and the pooled ratio is recomputed over the drawn scenes. When
tasks of a scene move together the scene-level interval is the wider, honest one; the task-level
one is printed beside it for comparison with the earlier notes.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.eval.clio import ClioScores


@dataclass(frozen=True)
class Difference:
    """`a - b` of a metric with its bootstrap interval (`low`, `high`) at `level`."""

    mean: float
    low: float
    high: float
    level: float

    @property
    def significant(self) -> bool:
        return self.low > 0 or self.high < 0

    def __str__(self) -> str:
        return f"{self.mean:+.3f} [{self.low:+.3f}, {self.high:+.3f}]"


def _units(scores: ClioScores, keys: list[str]) -> np.ndarray:
    """(tasks, 4) strict count, relaxed count, IoU sum and GT count per task, in `keys` order."""
    try:
        return np.array(
            [[s.strict, s.relaxed, s.iou_sum, s.num_gt] for s in (scores.per_task[k] for k in keys)], float
        )
    except KeyError as exc:
        raise InputError(f"rows were scored on different tasks (missing {exc})") from None


def _resampling_units(units: np.ndarray, keys: list[str], groups: Mapping[str, str] | None) -> np.ndarray:
    """The rows the bootstrap draws: one per task, or with `groups` one per group (the sums of its
    tasks' rows, so a drawn group brings all its tasks and the pooled ratio stays a ratio of sums)."""
    if groups is None:
        return units
    missing = [k for k in keys if k not in groups]
    if missing:
        raise InputError(f"no group (scene) given for task {missing[0]!r}")
    names = sorted({groups[k] for k in keys})
    index = {name: i for i, name in enumerate(names)}
    summed = np.zeros((len(names), units.shape[1]))
    np.add.at(summed, [index[groups[k]] for k in keys], units)
    return summed


def _draws(n: int, samples: int, seed: int) -> np.ndarray:
    if n == 0:
        raise InputError("no per-task scores to resample")
    return np.random.default_rng(seed).integers(0, n, size=(samples, n))


def paired_differences(
    a: ClioScores,
    b: ClioScores,
    *,
    samples: int = 4000,
    level: float = 0.95,
    seed: int = 0,
    groups: Mapping[str, str] | None = None,
    metrics: tuple[str, ...] = ("strict_osr", "iou"),
) -> dict[str, Difference]:
    """Strict-osR and IoU (or the `metrics` named, of strict_osr, relaxed_osr, iou) of `a` minus
    `b`, each with a paired bootstrap interval over tasks, or over the scenes `groups` assigns the
    tasks to (the same draw for both rows)."""
    keys = sorted(a.per_task)
    ua = _resampling_units(_units(a, keys), keys, groups)
    ub = _resampling_units(_units(b, keys), keys, groups)
    draws = _draws(len(ua), samples, seed)
    gt = ua[draws, 3].sum(axis=1)
    out: dict[str, Difference] = {}
    columns = {"strict_osr": 0, "relaxed_osr": 1, "iou": 2}
    for name, col in ((m, columns[m]) for m in metrics):
        diff = (ua[draws, col].sum(axis=1) - ub[draws, col].sum(axis=1)) / gt
        point = (ua[:, col].sum() - ub[:, col].sum()) / ua[:, 3].sum()
        tail = (1 - level) / 2
        out[name] = Difference(
            float(point), float(np.quantile(diff, tail)), float(np.quantile(diff, 1 - tail)), level
        )
    return out


@dataclass(frozen=True)
class Interval:
    """A metric's pooled value with its task-bootstrap percentile interval (`low`, `high`)."""

    value: float
    low: float
    high: float

    def __str__(self) -> str:
        return f"{self.value:.2f} [{self.low:.2f}, {self.high:.2f}]"


def score_intervals(
    scores: ClioScores,
    *,
    samples: int = 4000,
    level: float = 0.95,
    seed: int = 0,
    groups: Mapping[str, str] | None = None,
) -> dict[str, Interval]:
    """Strict-osR, Relaxed-osR and IoU of one row with intervals from resampling whole tasks, or
    whole scenes with `groups` (task key -> scene).

    The same resampling unit as `paired_differences`: a task's (task, GT) pairs move together,
    because one task's answers share a text query and are not independent.
    """
    keys = sorted(scores.per_task)
    units = _resampling_units(_units(scores, keys), keys, groups)
    draws = _draws(len(units), samples, seed)
    gt = np.maximum(units[draws, 3].sum(axis=1), 1.0)
    tail = (1 - level) / 2
    out: dict[str, Interval] = {}
    for name, col in (("strict_osr", 0), ("relaxed_osr", 1), ("iou", 2)):
        resampled = units[draws, col].sum(axis=1) / gt
        out[name] = Interval(
            float(units[:, col].sum() / units[:, 3].sum()),
            float(np.quantile(resampled, tail)),
            float(np.quantile(resampled, 1 - tail)),
        )
    return out
