"""`bfields calibrate` as a library call: fit the likelihoods' mu0 / mu1 / s for one CLIP model.

`calibrate(CalibrationRequest(...))` is the one typed entry point (the CLI only builds the
request from its flags). Two sources of scores:
- a file of (score, label) pairs the operator collected (CSV with a header `score,label`, or
  JSON: a list of {"score", "label"} or {"positive": [...], "negative": [...]});
- scenes with ground truth (the synthetic suite's `gt.json`, `calibration.ground_truth`): every
  mask is scored against every task; a (mask, task) pair is positive when most of the mask's
  visible Gaussians belong to a GT object of that task, and negative when the task has no GT
  object in the scene (the paper's recipe: mu0 from tasks without a relevant object, mu1 and s
  from known positives).
"""

from __future__ import annotations

import csv
import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from bayesian_fields_core.calibration.model import (
    Calibration,
    fit_calibration,
    load_calibration,
    save_calibration,
)
from bayesian_fields_core.errors import InputError
from bayesian_fields_core.eval.calibration.ground_truth import EXTRA_ABSENT_TASKS, Negatives
from bayesian_fields_core.eval.regime import PAPER_LIKELIHOODS, Regime


class CalibrationRequest(BaseModel):
    """What to calibrate from and where to write it. Exactly one of `scores` / `scenes`."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    out: Path = Field(description="Calibration JSON to write.")
    scores: Path | None = Field(None, description="CSV/JSON of (score, label) pairs; label 1 = relevant.")
    scenes: tuple[Path, ...] = Field((), description="Synthetic scene folders with gt.json.")
    profile: str | None = Field(None, description="Model profile YAML (default: the bundled one).")
    negatives: Negatives = Field("absent", description="With scenes: which pairs are negatives.")
    max_frames: int | None = Field(None, ge=1, description="With scenes: at most this many frames per scene.")
    model_id: str | None = Field(None, description="Model id recorded in the file (default: the encoder's).")
    regime: Regime = Field(
        "strong",
        description=(
            "With scenes: 'strong' scores the encoder as it is; 'realistic' the evaluation's "
            "weak-evidence embeddings (eval/regime.py): the likelihoods they give are printed, and "
            "the file keeps the regime's own with the threshold fitted in their margins."
        ),
    )
    keep_likelihoods: Path | None = Field(
        None,
        description=(
            "With scenes: keep mu0 / mu1 / s of this calibration file (fitted elsewhere, e.g. on "
            "crops) and fit only the 'not found' threshold in its margins."
        ),
    )
    absent_tasks: int = Field(
        EXTRA_ABSENT_TASKS,
        ge=0,
        description=(
            "With scenes: extra absent tasks per scene (the suite's rule for absent tasks), whose "
            "first answers the 'not found' threshold is fitted against."
        ),
    )
    cache: Path | None = Field(
        None, description="With scenes: perception cache folder kept between calls (default: temporary)."
    )

    def check(self) -> None:
        """Refuse a request without exactly one source, or a score file without a model id.

        (Not a pydantic validator: those would wrap the `InputError` into a ValidationError.)"""
        if (self.scores is None) == (not self.scenes):
            raise InputError("give either a score file or scenes with ground truth", source="calibrate")
        if self.keep_likelihoods is not None and not self.scenes:
            raise InputError("--keep-likelihoods goes with --scene (it fits the 'not found' threshold)")
        if self.scores is not None and not self.model_id:
            # A calibration is only used with the CLIP it was fitted for; without an id no profile
            # would ever accept the file.
            raise InputError(
                "--scores needs --model-id (the encoder's model id, e.g. tiny-clip@1d545f781fac)"
            )


def read_score_file(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(positive scores, negative scores) from a CSV or JSON score file."""
    if not path.is_file():
        raise InputError("file not found", source=str(path))
    text = path.read_text(encoding="utf-8")
    pos: list[float] = []
    neg: list[float] = []
    try:
        if path.suffix == ".json":
            data = json.loads(text)
            if isinstance(data, dict):
                pos = [float(v) for v in data.get("positive", [])]
                neg = [float(v) for v in data.get("negative", [])]
            else:
                for row in data:
                    (pos if int(row["label"]) else neg).append(float(row["score"]))
        else:
            reader = csv.DictReader(text.splitlines())
            if reader.fieldnames is None or not {"score", "label"} <= set(reader.fieldnames):
                raise InputError("CSV needs a header with 'score' and 'label' columns", source=str(path))
            for row in reader:
                (pos if int(row["label"]) else neg).append(float(row["score"]))
    except (KeyError, ValueError, TypeError, json.JSONDecodeError) as exc:
        if isinstance(exc, InputError):
            raise
        raise InputError(f"cannot read scores: {exc}", source=str(path)) from None
    if not pos or not neg:
        raise InputError(
            f"need both positive and negative scores (got {len(pos)} and {len(neg)})", source=str(path)
        )
    return np.asarray(pos), np.asarray(neg)


def calibrate(request: CalibrationRequest, log: Callable[[str], None] = print) -> Calibration:
    """Fit and write the calibration `request` describes; returns it. `log` says what the
    scenes gave where the file keeps other likelihoods (the realistic regime)."""
    request.check()
    if request.scores is not None:
        pos, neg = read_score_file(request.scores)
        cal = fit_calibration(pos, neg, str(request.model_id))
    else:
        from bayesian_fields_core.eval.calibration.ground_truth import collect_scores
        from bayesian_fields_core.eval.calibration.not_found_fit import fit_answer_min_peak

        labels, encoder_id = collect_scores(
            list(request.scenes),
            request.profile,
            max_frames=request.max_frames,
            negatives=request.negatives,
            regime=request.regime,
            extra_absent=request.absent_tasks,
            cache_dir=request.cache,
        )
        model_id = request.model_id or encoder_id
        if request.keep_likelihoods is not None:
            kept = load_calibration(request.keep_likelihoods, model_id=model_id)
            cal = kept.model_copy(update={"answer_min_peak": None, "not_found_fit": None})
        else:
            cal = fit_calibration(labels.positive, labels.negative, model_id)
        if request.regime == "realistic":
            # The regime fuses with its target likelihoods whatever these scenes give: the
            # threshold is fitted, and stored, in the margins every run of the regime computes.
            log(f"likelihoods these scenes give: mu0={cal.mu0:.4f} mu1={cal.mu1:.4f} s={cal.s:.4f}")
            cal = regime_calibration(cal)
        cal = fit_answer_min_peak(labels.peaks, cal)
    save_calibration(request.out, cal)
    return cal


def regime_calibration(fitted: Calibration) -> Calibration:
    """`fitted`'s counts with the realistic regime's likelihoods (`PAPER_LIKELIHOODS`)."""
    target = PAPER_LIKELIHOODS
    return fitted.model_copy(
        update={
            "mu0": target.mu0,
            "mu1": target.mu1,
            "s": target.s,
            "answer_min_peak": None,
            "not_found_fit": None,
        }
    )
