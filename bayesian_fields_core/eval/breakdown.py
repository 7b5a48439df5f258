"""Where a map fails a task (issue #14, item 6): each missed (task, GT object) pair gets a cause.

Table 1 says how many GT objects a row finds; this says why the others were not found, from the
boxes alone, against every instance of the synthetic scene's ground truth:
- "merged": the answer overlapping the GT object also holds another instance's centre (a
  neighbour object or clutter item): under-segmentation;
- "split": the answer overlaps the GT object but is a fragment of it (its box is under half the
  GT box's volume, or misses the GT centre while being smaller): over-segmentation;
- "wrong instance": no answer touches the GT object, but the task was answered elsewhere (a
  look-alike, a same-colour neighbour);
- "missed": the task got fewer answers than GT objects and none touched this one;
- "other": an overlapping answer that is neither (too big with only background inside).
A strict detection is "ok". Answers are the same top-k queries as `clio.clio_metrics`.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from bayesian_fields_core.eval.box_iou import obb_contains_centroid, obb_iou_matrix
from bayesian_fields_core.eval.clio import EstimatedObject, GTObject, top_k_for_task
from bayesian_fields_core.eval.tables import render_table
from bayesian_fields_core.geometry.obb import OrientedBox

CAUSES: tuple[str, ...] = ("ok", "merged", "split", "wrong instance", "missed", "other")


@dataclass(frozen=True)
class SceneInstance:
    """An instance of the scene's ground truth that an answer may swallow (object or clutter)."""

    name: str
    box: OrientedBox


@dataclass
class TaskBreakdown:
    """One task's GT objects, each with its cause (`CAUSES`)."""

    scene: str
    task: str
    causes: list[str] = field(default_factory=list)

    @property
    def kind(self) -> str:
        """ "label", "coarse" ("all the ..."), or "fine": the task families of the capture suite."""
        if self.task.endswith(" label"):
            return "label"
        return "coarse" if " all the " in f" {self.task} " else "fine"


def _volume(box: OrientedBox) -> float:
    return float(np.prod(box.extents))


def classify_task(
    task: str,
    gt_boxes: Sequence[OrientedBox],
    answers: Sequence[OrientedBox],
    instances: Sequence[SceneInstance],
) -> list[str]:
    """The cause for each GT box of one task, given the task's top-k answer boxes."""
    iou = obb_iou_matrix(list(gt_boxes), list(answers))
    # The same one-to-one greedy matching as Clio's metrics, for "ok".
    matched: dict[int, int] = {}
    pairs = sorted(
        ((iou[g, e], g, e) for g in range(iou.shape[0]) for e in range(iou.shape[1])), reverse=True
    )
    used: set[int] = set()
    for value, g, a in pairs:
        if value <= 0 or g in matched or a in used:
            continue
        matched[g] = a
        used.add(a)
    causes = []
    for g, gt in enumerate(gt_boxes):
        e = matched.get(g)
        if e is not None and obb_contains_centroid(answers[e], gt) and obb_contains_centroid(gt, answers[e]):
            causes.append("ok")
            continue
        overlapping = [j for j in range(len(answers)) if iou[g, j] > 0]
        if not overlapping:
            causes.append("wrong instance" if answers else "missed")
            continue
        j = e if e is not None else max(overlapping, key=lambda k: iou[g, k])
        answer = answers[j]
        others = [
            inst
            for inst in instances
            if not np.allclose(inst.box.center, gt.center) and answer.contains(inst.box.center)
        ]
        if others:
            causes.append("merged")
        elif _volume(answer) < 0.5 * _volume(gt) or (
            not obb_contains_centroid(answer, gt) and _volume(answer) < _volume(gt)
        ):
            causes.append("split")
        else:
            causes.append("other")
    return causes


def task_breakdowns(
    scene: str,
    tasks: Sequence[str],
    estimates: Sequence[EstimatedObject],
    ground_truth: Sequence[GTObject],
    instances: Sequence[SceneInstance],
) -> list[TaskBreakdown]:
    """Every task's causes for one map of one scene (tasks without GT objects are skipped)."""
    out = []
    for task in tasks:
        gt_boxes = [g.box for g in ground_truth if g.task == task]
        if not gt_boxes:
            continue
        answers = [estimates[i].box for i in top_k_for_task(estimates, task, len(gt_boxes))]
        out.append(TaskBreakdown(scene, task, classify_task(task, gt_boxes, answers, instances)))
    return out


def format_breakdown(rows: Sequence[TaskBreakdown], *, markdown: bool = False, per_task: bool = True) -> str:
    """Counts of causes per task family (fine / label / coarse) and, with `per_task`, per task."""
    header = ["Task", "GT", *CAUSES]
    body = []
    families: dict[str, Counter[str]] = {}
    for r in rows:
        families.setdefault(r.kind, Counter()).update(r.causes)
        if per_task:
            c = Counter(r.causes)
            body.append([f"{r.scene}: {r.task}", str(len(r.causes)), *(str(c[k]) for k in CAUSES)])
    total: Counter[str] = Counter()
    for kind in ("fine", "label", "coarse"):
        if kind in families:
            c = families[kind]
            total.update(c)
            body.append([f"all {kind} tasks", str(sum(c.values())), *(str(c[k]) for k in CAUSES)])
    body.append(["all tasks", str(sum(total.values())), *(str(total[k]) for k in CAUSES)])
    return render_table(header, body, markdown=markdown)
