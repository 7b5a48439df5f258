"""`bfields calibrate`: fit the likelihoods' mu0 / mu1 / s for one CLIP model, write the file.

Two sources of scores:
- a file of (score, label) pairs the operator collected (CSV with a header `score,label`, or
  JSON: a list of {"score", "label"} or {"positive": [...], "negative": [...]});
- scenes with ground truth (the synthetic suite's `gt.json`): every mask is scored against every
  task; a (mask, task) pair is positive when most of the mask's visible Gaussians belong to a GT
  object of that task, and negative when the task has no GT object in the scene (the paper's
  recipe: mu0 from tasks without a relevant object, mu1 and s from known positives).
"""

from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .errors import InputError
from .fusion.calibration import fit_calibration, save_calibration

if TYPE_CHECKING:
    from .eval.ground_truth_scores import Negatives

POSITIVE_OVERLAP = 0.5  # share of a mask's Gaussians inside a GT object for a positive pair


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


def scene_scores(
    scene_dirs: list[Path],
    profile: str | None,
    max_frames: int | None = None,
    negatives: Negatives = "absent",
) -> tuple[np.ndarray, np.ndarray, str]:
    """Positive/negative cosine scores from synthetic scenes with ground truth."""
    from .eval.ground_truth_scores import collect_scores

    return collect_scores(
        scene_dirs,
        profile,
        positive_overlap=POSITIVE_OVERLAP,
        max_frames=max_frames,
        negatives=negatives,
    )


def calibrate(args: argparse.Namespace) -> None:
    if args.scores:
        if not args.model_id:
            # A calibration is only used with the CLIP it was fitted for; without an id no profile
            # would ever accept the file.
            raise InputError(
                "--scores needs --model-id (the encoder's model id, e.g. tiny-clip@b8b6386ff433)"
            )
        pos, neg = read_score_file(Path(args.scores))
        model_id = args.model_id
    else:
        pos, neg, encoder_id = scene_scores(
            [Path(p) for p in args.scene], args.profile, args.max_frames, args.negatives
        )
        model_id = args.model_id or encoder_id
    cal = fit_calibration(pos, neg, model_id)
    save_calibration(args.out, cal)
    print(
        f"calibration for {model_id}: mu0={cal.mu0:.4f} mu1={cal.mu1:.4f} s={cal.s:.4f} "
        f"({len(pos)} positive, {len(neg)} negative scores) -> {args.out}"
    )
