"""Clio's task-driven object metrics (Strict-osR, Relaxed-osR, IoU, Objs) and the paper's Table 1.

Protocol (Maggio et al., RA-L 2024, as used by the Bayesian Fields paper):
- For every task with `k` ground-truth objects, query the map for its `k` most probable objects
  (`p(task | object)`, ties broken by map order).
- Match queried objects to GT objects one-to-one by oriented-box IoU. Clio's evaluation code matches
  greedily: repeatedly take the pair with the highest IoU and remove both, stopping when the best
  remaining IoU is 0 (`matching="greedy"`, the default, so our numbers compare with the paper's).
  `matching="hungarian"` maximises the total IoU instead (scipy `linear_sum_assignment`); pairs
  with IoU 0 stay unmatched in both modes.
- A matched pair is a *strict* detection when each box contains the other's centroid, a *relaxed*
  one when either does (the paper's definition; Clio's code counts only "the estimate contains the
  GT centroid", selectable with `relaxed="estimate_contains_gt"`). Centroids are box centres, as
  in Clio's code.
- Strict-osR and Relaxed-osR divide those counts by the number of GT objects over all tasks; IoU is
  the sum of matched IoUs over the same denominator (unmatched GT objects count as 0); Objs is
  the number of objects in the map.

Containment here is the true oriented test. (Clio's code tests centroids against an axis-aligned
box of twice the extent, which is looser; we follow the paper's definition instead. The
"Clio-code" scoring of `clio_code.py` reproduces Clio's rules, to set a figure beside the paper's.)
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial.transform import Rotation

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.eval.box_iou import obb_contains_centroid, obb_iou_matrix
from bayesian_fields_core.eval.tables import render_table
from bayesian_fields_core.geometry.obb import OrientedBox

Matching = Literal["greedy", "hungarian"]
RelaxedRule = Literal["either", "estimate_contains_gt"]
Containment = Callable[[OrientedBox, OrientedBox], bool]
"""`contains(container, other)`: whether `container` holds the centre of `other`."""


@dataclass
class EstimatedObject:
    """An object of the estimated map: its box and `p(task | object)` for each task name."""

    box: OrientedBox
    probabilities: Mapping[str, float]


@dataclass
class GTObject:
    """A ground-truth object relevant to `task`."""

    task: str
    box: OrientedBox


@dataclass
class TaskScores:
    """Counts for one task (the totals are sums of these)."""

    num_gt: int
    strict: int
    relaxed: int
    iou_sum: float


@dataclass
class ClioScores:
    """Clio's metrics for one map; `time_s` optional (the paper reports minutes per scene)."""

    strict_osr: float
    relaxed_osr: float
    iou: float
    num_objects: int
    num_gt: int
    per_task: dict[str, TaskScores] = field(default_factory=dict)
    time_s: float | None = None

    def to_dict(self) -> dict[str, Any]:
        return {
            "strict_osr": self.strict_osr,
            "relaxed_osr": self.relaxed_osr,
            "iou": self.iou,
            "num_objects": self.num_objects,
            "num_gt": self.num_gt,
            "time_s": self.time_s,
            "per_task": {k: vars(v) for k, v in self.per_task.items()},
        }


def _box(value: OrientedBox | Mapping[str, Any]) -> OrientedBox:
    return value if isinstance(value, OrientedBox) else OrientedBox.from_dict(value)


def _coerce_estimate(obj: EstimatedObject | Mapping[str, Any]) -> EstimatedObject:
    if isinstance(obj, EstimatedObject):
        return obj
    try:
        return EstimatedObject(box=_box(obj["box"]), probabilities=dict(obj["probabilities"]))
    except KeyError as exc:
        raise InputError(f"estimated object: missing field {exc.args[0]!r}") from None


def _coerce_gt(obj: GTObject | Mapping[str, Any]) -> GTObject:
    if isinstance(obj, GTObject):
        return obj
    try:
        return GTObject(task=str(obj["task"]), box=_box(obj["box"]))
    except KeyError as exc:
        raise InputError(f"ground-truth object: missing field {exc.args[0]!r}") from None


def _match(iou: np.ndarray, matching: Matching) -> list[tuple[int, int]]:
    """One-to-one (gt, estimate) pairs with positive IoU."""
    if iou.size == 0:
        return []
    if matching == "hungarian":
        rows, cols = linear_sum_assignment(-iou)
        return [(int(r), int(c)) for r, c in zip(rows, cols, strict=True) if iou[r, c] > 0]
    if matching != "greedy":
        raise InputError(f"clio metrics: unknown matching {matching!r} (greedy or hungarian)")
    pairs: list[tuple[int, int]] = []
    used_gt: set[int] = set()
    used_est: set[int] = set()
    order = np.argsort(-iou, axis=None, kind="stable")
    for flat in order:  # at most k^2 pairs per task, k = a handful of GT objects
        g, e = np.unravel_index(flat, iou.shape)
        if iou[g, e] <= 0:
            break
        if g in used_gt or e in used_est:
            continue
        pairs.append((int(g), int(e)))
        used_gt.add(int(g))
        used_est.add(int(e))
    return pairs


def top_k_for_task(estimates: Sequence[EstimatedObject], task: str, k: int) -> list[int]:
    """Indices of the k estimates most probable for `task` (stable: ties keep map order)."""
    probs = np.array([float(e.probabilities.get(task, 0.0)) for e in estimates], dtype=np.float64)
    return np.argsort(-probs, kind="stable")[: min(k, len(estimates))].tolist()


def clio_metrics(
    estimates: Sequence[EstimatedObject | Mapping[str, Any]],
    ground_truth: Sequence[GTObject | Mapping[str, Any]],
    *,
    num_objects: int | None = None,
    matching: Matching = "greedy",
    relaxed: RelaxedRule = "either",
    time_s: float | None = None,
    contains: Containment = obb_contains_centroid,
) -> ClioScores:
    """Clio's metrics of a map (`estimates`) against task-labelled GT boxes.

    `num_objects` (the Objs column) defaults to `len(estimates)`; pass the map's object count when
    only part of the map is given. `contains` is the centroid test (the oriented one by default;
    `clio_code.clio_code_contains` for Clio's code).
    """
    ests = [_coerce_estimate(e) for e in estimates]
    gts = [_coerce_gt(g) for g in ground_truth]
    if not gts:
        raise InputError("clio metrics: no ground-truth objects")
    if relaxed not in ("either", "estimate_contains_gt"):
        raise InputError(f"clio metrics: unknown relaxed rule {relaxed!r}")
    tasks = list(dict.fromkeys(g.task for g in gts))  # first-seen order
    per_task: dict[str, TaskScores] = {}
    for task in tasks:
        gt_boxes = [g.box for g in gts if g.task == task]
        chosen = [ests[i].box for i in top_k_for_task(ests, task, len(gt_boxes))]
        iou = obb_iou_matrix(gt_boxes, chosen)
        scores = TaskScores(num_gt=len(gt_boxes), strict=0, relaxed=0, iou_sum=0.0)
        for g, e in _match(iou, matching):
            scores.iou_sum += float(iou[g, e])
            est_has_gt = contains(chosen[e], gt_boxes[g])
            gt_has_est = contains(gt_boxes[g], chosen[e])
            scores.strict += int(est_has_gt and gt_has_est)
            scores.relaxed += int(est_has_gt or (relaxed == "either" and gt_has_est))
        per_task[task] = scores
    total = sum(s.num_gt for s in per_task.values())
    return ClioScores(
        strict_osr=sum(s.strict for s in per_task.values()) / total,
        relaxed_osr=sum(s.relaxed for s in per_task.values()) / total,
        iou=sum(s.iou_sum for s in per_task.values()) / total,
        num_objects=len(ests) if num_objects is None else int(num_objects),
        num_gt=total,
        per_task=per_task,
        time_s=time_s,
    )


def load_clio_ground_truth(data: Mapping[str, Any], *, source: str = "ground truth") -> list[GTObject]:
    """GT objects from Clio's task YAML (already parsed): `{task: [{center, extents, rotation}]}`,
    `rotation` a quaternion as `{w, x, y, z}` or `[w, x, y, z]`, or a 3x3 matrix."""
    if not isinstance(data, Mapping):
        raise InputError("expected a mapping of task -> list of boxes", source=source)
    out: list[GTObject] = []
    for task, boxes in data.items():
        if not isinstance(boxes, Sequence) or isinstance(boxes, str):
            raise InputError(f"task {task!r}: expected a list of boxes", source=source)
        for i, entry in enumerate(boxes):
            where = f"task {task!r} box {i}"
            try:
                rot = entry["rotation"]
                if isinstance(rot, Mapping):
                    quat_xyzw = [rot["x"], rot["y"], rot["z"], rot["w"]]
                    matrix = Rotation.from_quat(np.asarray(quat_xyzw, dtype=float)).as_matrix()
                elif np.shape(rot) == (4,):
                    w, x, y, z = (float(v) for v in rot)
                    matrix = Rotation.from_quat([x, y, z, w]).as_matrix()
                else:
                    matrix = np.asarray(rot, dtype=float)
                box = OrientedBox(entry["center"], matrix, entry["extents"])
            except KeyError as exc:
                raise InputError(f"{where}: missing field {exc.args[0]!r}", source=source) from None
            except (TypeError, ValueError) as exc:
                raise InputError(f"{where}: {exc}", source=source) from None
            out.append(GTObject(task=str(task), box=box))
    return out


_COLUMNS = ("Strict-osR", "Relaxed-osR", "IoU", "Objs")


def format_table(
    rows: Mapping[str, ClioScores], *, markdown: bool = False, show_time: bool | None = None
) -> str:
    """The paper's Table 1 layout: one row per method, Strict-osR, Relaxed-osR, IoU (2 decimals),
    Objs, and a time column (minutes) when any row has a time (or `show_time=True`)."""
    if show_time is None:
        show_time = any(s.time_s is not None for s in rows.values())
    header = ["Method", *_COLUMNS] + (["Time (min)"] if show_time else [])
    body = []
    for name, s in rows.items():
        cells = [name, f"{s.strict_osr:.2f}", f"{s.relaxed_osr:.2f}", f"{s.iou:.2f}", str(s.num_objects)]
        if show_time:
            cells.append("-" if s.time_s is None else f"{s.time_s / 60:.1f}")
        body.append(cells)
    return render_table(header, body, markdown=markdown)
