"""Per-CLIP-model calibration of the score Gaussians, fitted from labelled cosine scores.

`mu0` is the mean score of negatives (tasks with no relevant object in view), `mu1` the mean of
known positives. The model has one shared `s`; the paper takes it from the positives (0.035 on
COCO, Sec. 5), which is our default, with the pooled within-class standard deviation and the
negatives' as named alternatives. Files are small JSON documents keyed by the model id, so the
pipeline can refuse a calibration made for another encoder.
"""

from __future__ import annotations

import json
from pathlib import Path
from statistics import NormalDist
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.fusion.likelihood import LikelihoodParams
from bayesian_fields_core.params import default

SpreadMode = Literal["positive", "pooled", "negative"]


MAX_PRESENT_LOSS = 0.02
"""Share of present tasks the fitted 'not found' threshold may leave unanswered: a robot that
is told "not found" for an object that is there loses more than one that gets a weak answer for
one that is not, so the fit favours present answers."""


def distribution_min_peak(mu0: float, mu1: float, s: float, miss: float = MAX_PRESENT_LOSS) -> float:
    """The 'not found' threshold from the score Gaussians alone, for a calibration without a
    fitted one (e.g. from a score file): the margin below which a relevant view scores with
    probability `miss`, `1 - z(1 - miss) s / (mu1 - mu0)`. A present object's best view is the
    highest of several, so it falls below less often than that."""
    return float(1.0 - NormalDist().inv_cdf(1.0 - miss) * s / (mu1 - mu0))


class NotFoundFit(BaseModel):
    """How `answer_min_peak` was fitted: task counts, the rule that chose it, what it does on the
    fitting scenes, and the trade-off curve `[threshold, absent share not found, present share
    lost]` (margins of this calibration's likelihoods)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    absent_tasks: int = Field(ge=0)
    present_tasks: int = Field(ge=0)
    max_present_loss: float = Field(ge=0, le=1)
    absent_not_found: float = Field(ge=0, le=1)
    present_lost: float = Field(ge=0, le=1)
    curve: list[tuple[float, float, float]]


class Calibration(BaseModel):
    """Fitted score Gaussians of one encoder (`model_id`), plus the sample sizes behind them."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    model_id: str = Field(min_length=1)
    mu0: float
    mu1: float
    s: float = Field(gt=0)
    num_positive: int | None = Field(default=None, ge=0)
    num_negative: int | None = Field(default=None, ge=0)
    answer_min_peak: float | None = Field(
        default=None,
        ge=-10,
        le=10,
        description=(
            "The 'not found' threshold fitted for this encoder by `bfields calibrate --scene` "
            "(present and absent tasks of scenes with ground truth); None: not fitted, the "
            "pipeline falls back to `distribution_min_peak`."
        ),
    )
    not_found_fit: NotFoundFit | None = None

    @model_validator(mode="after")
    def _positives_score_higher(self) -> Calibration:
        if not (np.isfinite(self.mu0) and np.isfinite(self.mu1) and np.isfinite(self.s)):
            raise ValueError("mu0, mu1 and s must be finite")
        if self.mu1 <= self.mu0:
            raise ValueError(f"mu1 ({self.mu1}) must exceed mu0 ({self.mu0}): positives must score higher")
        return self

    def to_likelihood_params(self, s_eps: float = default("s_eps")) -> LikelihoodParams:
        """The measurement model for this encoder, with optional extra noise `s_eps`."""
        return LikelihoodParams(mu0=self.mu0, mu1=self.mu1, s=self.s, s_eps=s_eps)


def _scores(values: np.ndarray, name: str) -> np.ndarray:
    arr = np.asarray(values, dtype=np.float64).reshape(-1)
    if arr.size < 2:
        raise InputError(f"need at least 2 scores, got {arr.size}", source=f"calibration.{name}")
    if not np.all(np.isfinite(arr)):
        raise InputError("scores must be finite", source=f"calibration.{name}")
    return arr


def fit_calibration(
    positive_scores: np.ndarray,
    negative_scores: np.ndarray,
    model_id: str,
    *,
    spread: SpreadMode = "positive",
) -> Calibration:
    """Fit `mu1`, `mu0` as the class means and `s` by `spread` (sample std, ddof=1).

    spread: "positive" (paper), "negative", or "pooled" (within-class std of both classes,
    weighted by degrees of freedom).
    """
    pos = _scores(positive_scores, "positive_scores")
    neg = _scores(negative_scores, "negative_scores")
    if spread == "positive":
        s = float(pos.std(ddof=1))
    elif spread == "negative":
        s = float(neg.std(ddof=1))
    elif spread == "pooled":
        ss = ((pos - pos.mean()) ** 2).sum() + ((neg - neg.mean()) ** 2).sum()
        s = float(np.sqrt(ss / (pos.size + neg.size - 2)))
    else:
        raise InputError(f"unknown spread {spread!r}", source="calibration.spread")
    try:
        return Calibration(
            model_id=model_id,
            mu0=float(neg.mean()),
            mu1=float(pos.mean()),
            s=s,
            num_positive=int(pos.size),
            num_negative=int(neg.size),
        )
    except ValidationError as exc:
        raise InputError(str(exc), source="calibration") from exc


def save_calibration(path: str | Path, cal: Calibration) -> None:
    """Write the calibration as JSON."""
    Path(path).write_text(cal.model_dump_json(indent=2) + "\n", encoding="utf-8")


def load_calibration(path: str | Path, *, model_id: str | None = None) -> Calibration:
    """Read a calibration JSON; when `model_id` is given, refuse one made for another model."""
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
        cal = Calibration.model_validate(data)
    except FileNotFoundError as exc:
        raise InputError("file not found", source=str(path)) from exc
    except (json.JSONDecodeError, ValidationError) as exc:
        raise InputError(f"not a valid calibration: {exc}", source=str(path)) from exc
    if model_id is not None and cal.model_id != model_id:
        raise InputError(f"calibration is for model {cal.model_id!r}, not {model_id!r}", source=str(path))
    return cal
