"""The LeRF protocol on a synthetic scene: render a map's objects in some of the scene's views
and score every (task, view) query against the ground-truth masks (paper Table 3's measure).

Queries are the tasks that have GT objects; a (task, view) pair is a query when the task's GT
objects cover at least `min_pixels` of the view (LeRF only queries what is visible). The GT mask
is the union of those objects' pixels in a rendered GT instance-id image; the predicted mask is
the union of the pixels of the objects that `lerf.select_objects` picks from the map's per-object
task probabilities. Both id images come from the same renderer with the same boundary erosion,
so a perfect map scores an IoU of 1.

Views: `n_views` capture frames spread evenly over the orbit. They are frames the map was built
from; the synthetic scenes have no held-out images, and the id images are rendered from the splat,
so what is scored is the 3D segmentation seen from those poses, not a photograph.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.eval.lerf import DEFAULT_RATIO, LerfScores, lerf_scores, query_iou
from bayesian_fields_core.eval.synthetic.ground_truth import load_ground_truth
from bayesian_fields_core.eval.synthetic.id_images import IdImageRenderer
from bayesian_fields_core.scene.types import Frame, Gaussians

DEFAULT_VIEWS = 4
DEFAULT_MIN_PIXELS = 50


@dataclass
class LerfViews:
    """The chosen views and their queries, rendered and masked once per scene and shared by every
    map scored on it: `gt_masks[v]` maps each task queried in view v to its GT mask."""

    gaussians: Gaussians
    frames: list[Frame]
    gt_masks: list[dict[str, np.ndarray]]


def prepare_views(
    folder: Path,
    gaussians: Gaussians,
    frames: list[Frame],
    n_views: int = DEFAULT_VIEWS,
    *,
    min_pixels: int = DEFAULT_MIN_PIXELS,
) -> LerfViews:
    """Pick `n_views` frames evenly, render the scene's GT instance-id image in each and keep
    the GT mask of every task whose objects cover at least `min_pixels` there."""
    if n_views < 1 or not frames:
        raise InputError(f"lerf: need at least one view and one frame, got {n_views} of {len(frames)}")
    gt = load_ground_truth(folder)
    picks = np.unique(np.linspace(0, len(frames) - 1, min(n_views, len(frames))).round().astype(int))
    chosen = [frames[i] for i in picks]
    renderer = IdImageRenderer(gaussians, gt.instance_ids)
    task_instances = {
        t.text: np.array([o.instance_id for o in t.objects], dtype=np.int64) for t in gt.tasks if t.objects
    }
    gt_masks = []
    for frame in chosen:
        ids = renderer.render(frame.K, frame.world_to_camera, frame.width, frame.height)
        masks = {task: np.isin(ids, instances) for task, instances in task_instances.items()}
        gt_masks.append({task: m for task, m in masks.items() if np.count_nonzero(m) >= min_pixels})
    return LerfViews(gaussians=gaussians, frames=chosen, gt_masks=gt_masks)


def score_map(
    views: LerfViews,
    tasks: list[str],
    object_ids: np.ndarray,
    task_probabilities: np.ndarray,
    *,
    ratio: float = DEFAULT_RATIO,
) -> LerfScores:
    """mIoU / mAcc of one map: `object_ids` (N,) per Gaussian (-1 none), `task_probabilities`
    (O, T) each object's probability for each of `tasks`."""
    object_ids = np.asarray(object_ids)
    probabilities = np.asarray(task_probabilities, dtype=np.float64)
    if probabilities.ndim != 2 or probabilities.shape[1] != len(tasks):
        raise InputError(f"lerf: expected (O, {len(tasks)}) task probabilities, got {probabilities.shape}")
    renderer = IdImageRenderer(views.gaussians, object_ids)
    ious: list[float] = []
    for frame, gt_masks in zip(views.frames, views.gt_masks, strict=True):
        ids = renderer.render(frame.K, frame.world_to_camera, frame.width, frame.height)
        for t, task in enumerate(tasks):
            gt_mask = gt_masks.get(task)
            if gt_mask is not None:
                ious.append(query_iou(probabilities[:, t], ids, gt_mask, ratio=ratio))
    return lerf_scores(ious)
