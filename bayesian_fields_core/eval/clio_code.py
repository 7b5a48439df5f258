"""The "Clio-code" scoring: Table 1's metrics by the rules of Clio's evaluation code, so a figure
can be set beside the paper's (issue 33).

The paper's Table 1 figures come from Clio's evaluation code, not from the definitions written in
the paper, and the two differ. The project's own scoring (`clio.py`, "geometric") follows the
written definitions; this module follows the code. Rules, read in MIT-SPARK/Clio at commit
f912b7c08fb0e029d80fd6b05eccee5009199ce4 (files under `clio_eval/`):

1. **Containment is axis-aligned with the box's full extent on each side of the centre.**
   `utils.py`, `EvalObjects.contains_centroid` (lines 23-35) and `centroid_contained_in`
   (lines 37-50) build the bounds `centre - extent .. centre + extent`, where `extent` is
   Open3D's `OrientedBoundingBox.extent`, the *full* side lengths: the tested box is twice the
   real one along each axis, and its rotation is ignored. `is_point_inside_box` (lines 154-157)
   compares with `<=` on both sides (a point on the boundary is inside).
2. **Relaxed counts only when the estimate contains the GT centre; Strict needs both ways.**
   `evaluate_helpers.py`, `compute_recall_and_iou` (lines 147-150): the weak (Relaxed) count
   goes up when `best_est_obj.contains_centroid(best_gt_bbox)`, and only then the strict count
   when also `best_est_obj.centroid_contained_in(best_gt_bbox)`.
3. **Greedy pairing by IoU, IoU summed over matched pairs** (the same as `clio.py`'s default):
   `compute_recall_and_iou` lines 130-154 repeatedly take the (GT, estimate) pair of highest
   IoU (first found on ties: GT order, then estimate order), stop when the best IoU is 0, and
   remove both; the k = number-of-GT estimates are the k most similar to the task
   (`utils.get_k_relevant_objects`, lines 231-242).
4. **Per scene, then averaged over scenes.** `compute_recall_and_iou` returns
   `matches / total_gt_objects` over one scene's tasks (line 165), and
   `experiments/evaluate_ablations.py`, `evaluate` (lines 40-75) produces one `Results` per
   dataset (scene); the paper's figure over several scenes is the unweighted mean of those
   per-scene figures (`scene_mean`), whereas the project pools every (task, GT object) pair of
   the suite (`suite.pool_scores`), which weights a scene by its number of GT objects.

IoU itself (exact oriented-box IoU, `box_iou.py`) and the pairing agree with Clio's, so only
Strict-osR and Relaxed-osR, and the way scenes are combined, differ between the two scorings.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.eval.clio import ClioScores, EstimatedObject, GTObject, clio_metrics
from bayesian_fields_core.geometry.obb import OrientedBox

CLIO_CODE_LABEL = "Clio-code"
"""How the CLI labels this scoring (the project's own is labelled "geometric")."""


def clio_code_contains(container: OrientedBox, other: OrientedBox) -> bool:
    """Clio's centroid test (rule 1): `other`'s centre inside `container.center +- extents`
    (full side lengths, so twice the box), axis-aligned, boundary included."""
    offset = np.abs(other.center - container.center)
    return bool(np.all(offset <= container.extents))


def clio_code_metrics(
    estimates: Sequence[EstimatedObject | Mapping[str, Any]],
    ground_truth: Sequence[GTObject | Mapping[str, Any]],
    *,
    num_objects: int | None = None,
    time_s: float | None = None,
) -> ClioScores:
    """One scene scored by Clio's code: rules 1-3 (greedy pairing, Relaxed = the estimate holds
    the GT centre, Strict = both ways, both by `clio_code_contains`)."""
    return clio_metrics(
        estimates,
        ground_truth,
        num_objects=num_objects,
        matching="greedy",
        relaxed="estimate_contains_gt",
        time_s=time_s,
        contains=clio_code_contains,
    )


def scene_mean(per_scene: Sequence[ClioScores]) -> ClioScores:
    """Rule 4: the unweighted mean over scenes of each scene's Strict-osR, Relaxed-osR and IoU
    (and of Objs and time). `per_task` is left empty: a mean of per-scene ratios is not a pooled
    ratio, so the task bootstrap does not apply to it."""
    if not per_scene:
        raise InputError("clio-code scoring: no scenes to average")
    times = [s.time_s for s in per_scene if s.time_s is not None]
    return ClioScores(
        strict_osr=float(np.mean([s.strict_osr for s in per_scene])),
        relaxed_osr=float(np.mean([s.relaxed_osr for s in per_scene])),
        iou=float(np.mean([s.iou for s in per_scene])),
        num_objects=int(round(float(np.mean([s.num_objects for s in per_scene])))),
        num_gt=sum(s.num_gt for s in per_scene),
        time_s=float(np.mean(times)) if times else None,
    )
