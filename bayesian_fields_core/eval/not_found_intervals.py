"""The "not found" shares with scene-level intervals (issue 46): how sure a held-out answer is.

A suite has one or two absent tasks per scene and tasks of one scene share one map, so the
resampling unit is the scene, as for Table 1's scene-level intervals (`bootstrap.py`): a drawn
scene brings all its tasks and each share is recomputed as a ratio of sums over the drawn scenes.
Two shares, at one threshold: absent tasks answered "not found" (the rule's purpose) and present
tasks left unanswered (its cost; a present task with no candidate at all counts as lost), and
beside them the part of the cost the threshold makes: present tasks with a candidate that it
rejects, of the present tasks with a candidate (the others are unanswered at any threshold).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from bayesian_fields_core.eval.not_found_tradeoff import TaskOutcome
from bayesian_fields_core.objects.not_found import is_not_found

SAMPLES = 4000
"""Bootstrap draws (as Table 1's intervals)."""
LEVEL = 0.95


@dataclass(frozen=True)
class Share:
    """`hits` of `total` with a percentile interval (`low`, `high`) from resampling scenes."""

    hits: int
    total: int
    low: float
    high: float

    @property
    def value(self) -> float:
        return self.hits / self.total if self.total else float("nan")

    def __str__(self) -> str:
        if not self.total:
            return "-"
        return f"{self.hits}/{self.total} = {100 * self.value:.1f}% [{100 * self.low:.1f}, {100 * self.high:.1f}]"


@dataclass(frozen=True)
class NotFoundShares:
    """The rule at `threshold` over `scenes` scenes: absent answered "not found", present lost."""

    threshold: float | None
    scenes: int
    absent_not_found: Share
    present_lost: Share
    present_lost_to_threshold: Share


def _per_scene(outcomes: Sequence[TaskOutcome], threshold: float | None) -> tuple[list[str], np.ndarray]:
    """(scene names, (scenes, 6) counts: absent, absent not found, present, present lost,
    present with a candidate, those of them the threshold rejects)."""
    names = sorted({o.scene for o in outcomes})
    index = {name: i for i, name in enumerate(names)}
    counts = np.zeros((len(names), 6))
    for o in outcomes:
        nf = is_not_found(o.score, threshold)
        row = counts[index[o.scene]]
        if o.absent:
            row[0] += 1
            row[1] += nf
        else:
            row[2] += 1
            row[3] += nf
            if not is_not_found(o.score, None):  # it has a candidate
                row[4] += 1
                row[5] += nf
    return names, counts


def _share(hits: np.ndarray, total: np.ndarray, draws: np.ndarray) -> Share:
    """The pooled share and its percentile interval over the drawn scene sets."""
    h, t = hits[draws].sum(axis=1), total[draws].sum(axis=1)
    ratios = np.divide(h, t, out=np.full(len(h), np.nan), where=t > 0)
    ratios = ratios[np.isfinite(ratios)]
    tail = (1 - LEVEL) / 2
    low, high = np.quantile(ratios, [tail, 1 - tail]) if len(ratios) else (np.nan, np.nan)
    return Share(int(hits.sum()), int(total.sum()), float(low), float(high))


def not_found_shares(
    outcomes: Sequence[TaskOutcome], threshold: float | None, *, samples: int = SAMPLES, seed: int = 0
) -> NotFoundShares:
    """Both shares at `threshold`, with 95 % intervals resampling scenes (`TaskOutcome.scene`)."""
    names, counts = _per_scene(outcomes, threshold)
    if not names:
        empty = Share(0, 0, float("nan"), float("nan"))
        return NotFoundShares(threshold, 0, empty, empty, empty)
    draws = np.random.default_rng(seed).integers(0, len(names), size=(samples, len(names)))
    return NotFoundShares(
        threshold,
        len(names),
        _share(counts[:, 1], counts[:, 0], draws),
        _share(counts[:, 3], counts[:, 2], draws),
        _share(counts[:, 5], counts[:, 4], draws),
    )


def format_shares(shares: NotFoundShares, label: str) -> str:
    """One line: the threshold (and where it comes from), both shares with their intervals."""
    shown = "None (rule off)" if shares.threshold is None else f"{shares.threshold:.4f}"
    return (
        f"  {label} {shown}: absent answered 'not found' {shares.absent_not_found}; present lost "
        f"{shares.present_lost}, of which the threshold rejects {shares.present_lost_to_threshold} "
        f"of the present tasks with a candidate (95%, bootstrap over the {shares.scenes} scenes)"
    )
