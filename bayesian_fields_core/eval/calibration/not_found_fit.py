"""`answer_min_peak` fitted by a procedure: `bfields calibrate --scene` (issue 23, item 4).

The "not found" rule leaves a task unanswered when its first answer's best view scores below a
margin. A threshold picked by hand on one suite did not carry over (on the capture suite's
held-out seeds 0.83 lost 12.9 % of the present answers), so the calibration fits it where it fits
the likelihoods: on scenes with ground truth, each task's first answer (the full pipeline, rule
off) is known to be for a present or an absent task; the fit takes the threshold that answers the
most absent tasks "not found" while losing at most `MAX_PRESENT_LOSS` of the present tasks that
have an answer, placed halfway between the highest absent peak it catches and the next peak
above (not on either). The whole trade-off curve is kept in the calibration file.
"""

from __future__ import annotations

from collections.abc import Sequence

from bayesian_fields_core.calibration.model import MAX_PRESENT_LOSS, Calibration, NotFoundFit
from bayesian_fields_core.eval.calibration.ground_truth import TaskPeak
from bayesian_fields_core.eval.not_found_tradeoff import TaskOutcome, best_threshold, tradeoff_curve


def peak_outcomes(peaks: Sequence[TaskPeak], cal: Calibration) -> list[TaskOutcome]:
    """Tasks with an answer as `TaskOutcome`s scored by their peak margin under `cal`'s
    likelihoods; a present task counts as one detection, so "recall lost" is the share of
    present tasks left unanswered. Tasks without any answer are "not found" at every threshold
    and take no part in the fit."""
    span = cal.mu1 - cal.mu0
    return [
        TaskOutcome(
            p.task,
            p.absent,
            (p.peak_score - cal.mu0) / span,
            num_gt=0 if p.absent else 1,
            strict=0 if p.absent else 1,
            relaxed=0 if p.absent else 1,
        )
        for p in peaks
        if p.peak_score is not None
    ]


def fit_answer_min_peak(
    peaks: Sequence[TaskPeak], cal: Calibration, max_present_loss: float = MAX_PRESENT_LOSS
) -> Calibration:
    """`cal` with `answer_min_peak` and `not_found_fit` set from the tasks' first-answer peaks;
    `cal` unchanged when the scenes hold no absent or no present task with an answer (nothing
    to fit against: the pipeline then uses the distribution threshold)."""
    outcomes = peak_outcomes(peaks, cal)
    absent = [o for o in outcomes if o.absent]
    present = [o for o in outcomes if not o.absent]
    if not absent or not present:
        return cal
    curve = tradeoff_curve(outcomes)
    best = best_threshold(curve, max_present_loss)
    scores = sorted({o.score for o in outcomes if o.score is not None})
    if best is None or best.threshold is None or best.absent_not_found == 0:
        return cal  # no threshold catches an absent task within the allowed loss
    below = [s for s in scores if s < best.threshold]
    threshold = (best.threshold + below[-1]) / 2 if below else best.threshold
    chosen = next(s for s in tradeoff_curve(outcomes, [threshold]))
    fit = NotFoundFit(
        absent_tasks=len(absent),
        present_tasks=len(present),
        max_present_loss=max_present_loss,
        absent_not_found=chosen.absent_share,
        present_lost=chosen.recall_lost,
        curve=[(float(s.threshold or 0.0), s.absent_share, s.recall_lost) for s in curve],
    )
    return cal.model_copy(update={"answer_min_peak": float(threshold), "not_found_fit": fit})
