"""The LeRF protocol of OpenGaussian, as the Bayesian Fields paper runs it (Table 3).

A query is one GT text label in one evaluation view. The map answers with a *set* of objects: every
object whose probability for the label is at least `ratio` (0.8) times the best object's, following
OpenGaussian's "fraction of the top score" rule. The predicted mask is the union of the pixels whose
rendered object id is in that set; its IoU against the GT mask is the query's score, and the query
is correct when that IoU exceeds `accuracy_threshold` (0.25). A scene's mIoU / mAcc are means over
its queries; the paper's "Mean" column is the unweighted mean of the per-scene figures.

The object-id images (per-pixel id of the object that dominates the rendered pixel, -1 for none)
come from the renderer; this module only scores them, so it stays independent of how masks are
rendered.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.eval.tables import render_table

DEFAULT_RATIO = 0.8
DEFAULT_ACCURACY_THRESHOLD = 0.25


@dataclass(frozen=True)
class LerfScores:
    """mIoU and mAcc as fractions in [0, 1] (multiply by 100 for the paper's table)."""

    miou: float
    macc: float
    num_queries: int

    def as_percent(self) -> tuple[float, float]:
        return 100.0 * self.miou, 100.0 * self.macc


def select_objects(probabilities: np.ndarray, ratio: float = DEFAULT_RATIO) -> np.ndarray:
    """Ids (indices) of the objects with probability >= ratio x the best one, ascending; none when
    no object has a positive probability (the rule would otherwise pick every object)."""
    p = np.asarray(probabilities, dtype=np.float64).reshape(-1)
    if p.size == 0:
        return np.zeros(0, dtype=np.int64)
    if not np.isfinite(p).all():
        raise InputError("lerf: object probabilities contain NaN or infinity")
    if not 0.0 < ratio <= 1.0:
        raise InputError(f"lerf: ratio must be in (0, 1], got {ratio}")
    if p.max() <= 0.0:
        return np.zeros(0, dtype=np.int64)
    return np.flatnonzero(p >= ratio * p.max())


def query_mask(id_image: np.ndarray, object_ids: np.ndarray) -> np.ndarray:
    """Boolean mask of the pixels whose object id is one of `object_ids` (-1 pixels never are)."""
    ids = np.asarray(id_image)
    if ids.ndim != 2:
        raise InputError(f"lerf: object-id image must be (H, W), got shape {ids.shape}")
    return np.isin(ids, np.asarray(object_ids)) & (ids >= 0)


def mask_iou(pred: np.ndarray, gt: np.ndarray) -> float:
    """IoU of two boolean masks of the same shape; an empty GT mask is an input error."""
    pred = np.asarray(pred, dtype=bool)
    gt = np.asarray(gt, dtype=bool)
    if pred.shape != gt.shape:
        raise InputError(f"lerf: predicted mask {pred.shape} and GT mask {gt.shape} differ in shape")
    if not gt.any():
        raise InputError("lerf: GT mask is empty")
    inter = np.count_nonzero(pred & gt)
    return inter / np.count_nonzero(pred | gt)


def query_iou(
    probabilities: np.ndarray, id_image: np.ndarray, gt_mask: np.ndarray, *, ratio: float = DEFAULT_RATIO
) -> float:
    """IoU of one query: object set by the ratio rule, mask from the id image, IoU vs GT."""
    return mask_iou(query_mask(id_image, select_objects(probabilities, ratio)), gt_mask)


def lerf_scores(
    ious: Sequence[float] | np.ndarray, *, accuracy_threshold: float = DEFAULT_ACCURACY_THRESHOLD
) -> LerfScores:
    """mIoU and accuracy (share of queries with IoU > threshold) of a scene's queries."""
    values = np.asarray(ious, dtype=np.float64).reshape(-1)
    if values.size == 0:
        raise InputError("lerf: no queries to score")
    return LerfScores(
        miou=float(values.mean()),
        macc=float((values > accuracy_threshold).mean()),
        num_queries=int(values.size),
    )


def mean_over_scenes(scenes: Mapping[str, LerfScores]) -> LerfScores:
    """The paper's Mean column: unweighted mean of the per-scene mIoU and mAcc."""
    if not scenes:
        raise InputError("lerf: no scenes to average")
    vals = list(scenes.values())
    return LerfScores(
        miou=float(np.mean([v.miou for v in vals])),
        macc=float(np.mean([v.macc for v in vals])),
        num_queries=sum(v.num_queries for v in vals),
    )


def format_lerf_table(rows: Mapping[str, Mapping[str, LerfScores]], *, markdown: bool = False) -> str:
    """Table 3's layout: one row per method, `mIoU / mAcc` (percent) per scene and their mean."""
    scenes = list(dict.fromkeys(s for per_scene in rows.values() for s in per_scene))
    header = ["Method", *scenes, "Mean"]
    body = []
    for method, per_scene in rows.items():
        cells = [method]
        for scene in scenes:
            cells.append(
                "-" if scene not in per_scene else "{:.2f} / {:.2f}".format(*per_scene[scene].as_percent())
            )
        cells.append("{:.2f} / {:.2f}".format(*mean_over_scenes(per_scene).as_percent()))
        body.append(cells)
    return render_table(header, body, markdown=markdown)
