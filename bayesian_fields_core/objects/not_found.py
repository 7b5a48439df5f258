""" "Not found" answers: a task whose best object does not carry enough evidence gets no object.

Selection (Eq. 7) always returns the top-k objects, so a task that names something the scene
does not hold ("pick up the red lamp") still gets a confident-looking answer, which a robot would
act on. The rule: a task is answered only when its best candidate's score reaches
`answer_min_peak`; otherwise its selection is empty and the result says why (`NotFound`,
format 1.3). The score is the best object's *best-view score* (`peak` in the code, and in
summary.json before format 1.6): the strongest single view any accepted mask gave it for the
task, as a margin `(phi - mu0) / (mu1 - mu0)` of the calibrated likelihoods (`fusion.peak` says
why the fused probability cannot serve: it saturates on look-alikes). The
README's "Not found answers" section shows how the threshold was chosen from the synthetic
suite's present and absent tasks.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from bayesian_fields_core.errors import InputError

if TYPE_CHECKING:  # the record is read by the light result reader: no torch / scipy at import
    from bayesian_fields_core.fusion.likelihood import LikelihoodParams

RULE = "best_view_score"
"""The score the rule thresholds: the best object's best single view for the task, as a margin
between the calibrated likelihood means (`fusion.peak`, `SelectedObject.peak`)."""

LEGACY_RULES = {"peak": RULE}
"""Older names of a rule (summary.json formats 1.3-1.5 wrote "peak"), read as today's."""

SCORE_MEANING = "1 = as well as a typical relevant view, 0 = as a typical irrelevant one"
"""What a best-view score means, said wherever one is printed (a bare number beside
probabilities reads like a broken probability: it can exceed 1)."""


@dataclass
class NotFound:
    """Why a task has no answer (format 1.3): its best candidate did not carry enough evidence.

    `rule` names the score the rule thresholds, `score` is the best candidate's value of it (None
    when no object qualified at all), `threshold` the least value that answers (None: rule off),
    `object_id` the rejected candidate (None when there was none), `reason` one readable line."""

    reason: str
    rule: str
    threshold: float | None
    score: float | None = None
    object_id: int | None = None

    def to_dict(self) -> dict[str, Any]:
        return {
            "reason": self.reason,
            "rule": self.rule,
            "threshold": None if self.threshold is None else float(self.threshold),
            "score": None if self.score is None else float(self.score),
            "object_id": None if self.object_id is None else int(self.object_id),
        }

    @classmethod
    def from_dict(cls, data: Any) -> NotFound:
        if not isinstance(data, dict):
            raise InputError("result summary: not_found must be an object")
        try:
            score, object_id, threshold = data.get("score"), data.get("object_id"), data["threshold"]
            found = cls(
                reason=str(data["reason"]),
                rule=LEGACY_RULES.get(str(data["rule"]), str(data["rule"])),
                threshold=None if threshold is None else float(threshold),
                score=None if score is None else float(score),
                object_id=None if object_id is None else int(object_id),
            )
            if str(data["rule"]) in LEGACY_RULES and None not in (score, object_id, threshold):
                # an older result's reason ("has peak 0.632 < 0.640806"), said as today's
                today = not_found_reason(found.object_id, found.score, found.threshold)
                if today is not None:  # None: today's rule would answer it; keep the stored words
                    found.reason = today.reason
            return found
        except KeyError as exc:
            raise InputError(f"result summary: not_found missing field {exc.args[0]!r}") from None
        except (TypeError, ValueError) as exc:
            raise InputError(f"result summary: malformed not_found ({exc})") from None


def resolve_answer_min_peak(
    value: float | str | None, calibration: object | None, likelihood: LikelihoodParams
) -> float | None:
    """The threshold a run applies: a number or None as given; 'calibrated' -> the encoder
    calibration's fitted `answer_min_peak` (`bfields calibrate --scene`), else, for a calibration
    without one (or a model without any), the margin a relevant view falls below 2 % of the time
    under the run's likelihoods (`calibration.model.distribution_min_peak`)."""
    if value != "calibrated":
        return None if value is None else float(value)
    fitted = getattr(calibration, "answer_min_peak", None)
    if fitted is not None:
        return float(fitted)
    from bayesian_fields_core.calibration.model import distribution_min_peak

    return distribution_min_peak(likelihood.mu0, likelihood.mu1, likelihood.s)


def is_not_found(score: float | None, threshold: float | None) -> bool:
    """True when a task whose best candidate scores `score` (None: no candidate) gets no answer.

    `threshold` None switches the rule off (only a task without any candidate is "not found")."""
    if score is None or not np.isfinite(score):
        return True
    return threshold is not None and score < threshold


def not_found_reason(
    object_id: int | None,
    score: float | None,
    threshold: float | None,
    rule: str = RULE,
) -> NotFound | None:
    """Why a task whose best candidate is `object_id` with rule score `score` gets no answer, or
    None when it is answered. No candidate at all (`object_id` None) is always "not found"; a
    candidate without a score (an older fusion artifact) is answered."""
    if object_id is None:
        return NotFound(reason="no object qualifies", rule=rule, threshold=threshold)
    if score is None or not is_not_found(score, threshold):
        return None
    return NotFound(
        reason=(
            f"best object {object_id} scored {score:.3f}, below the not-found threshold {threshold:.3f} "
            f"(its best view's match to the task: {SCORE_MEANING})"
        ),
        rule=rule,
        threshold=threshold,
        score=float(score),
        object_id=int(object_id),
    )
