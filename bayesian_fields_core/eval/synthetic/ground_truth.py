"""Ground truth of a synthetic scene on disk: ``gt.json`` (Clio style) + ``gt_gaussians.npz``.

``gt.json`` lists every instance and, per task, its GT objects with oriented boxes (center,
rotation 3x3 whose columns are the box axes, full extents), so the Clio metrics need nothing
else. Gaussian membership is stored once and compactly as a per-Gaussian instance id array in
``gt_gaussians.npz`` (``instance_ids``, the smallest integer type that fits); the ids of one
object's Gaussians are recovered from it, and the same array drives LeRF-style mask rendering.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.eval.synthetic.pieces import Instance, SyntheticScene
from bayesian_fields_core.eval.synthetic.tasks import TaskSpec

GT_JSON = "gt.json"
GT_ARRAYS = "gt_gaussians.npz"
FORMAT = "bayesian-fields-synthetic-gt"
VERSION = 1


@dataclass(frozen=True)
class GTObject:
    """One ground-truth instance with its oriented box and the ids of its Gaussians."""

    instance_id: int
    name: str
    kind: str
    colour: str | None
    category: str
    center: np.ndarray
    rotation: np.ndarray
    extents: np.ndarray
    gaussian_ids: np.ndarray

    def contains(self, points: np.ndarray, tol: float = 1e-6) -> np.ndarray:
        """(n,) bool: which points lie inside the oriented box."""
        local = (np.asarray(points, dtype=np.float64) - self.center) @ self.rotation
        return np.all(np.abs(local) <= self.extents / 2 + tol, axis=1)


@dataclass(frozen=True)
class GTTask:
    text: str
    granularity: str  # "fine", "coarse" or "absent"
    objects: list[GTObject]


@dataclass
class GroundTruth:
    tasks: list[GTTask]
    instances: list[GTObject]
    instance_ids: np.ndarray  # (N,) per-Gaussian instance id
    spec: dict

    @property
    def task_texts(self) -> list[str]:
        return [t.text for t in self.tasks]


def _box(instance: Instance) -> dict:
    return {
        "center": [float(v) for v in instance.center],
        "rotation": [[float(v) for v in row] for row in instance.rotation],
        "extents": [float(v) for v in instance.extents],
    }


def _instance_json(instance: Instance) -> dict:
    label = {} if instance.label is None else {"label": instance.label}
    return {
        "id": instance.id,
        "name": instance.name,
        "kind": instance.kind,
        "colour": instance.colour,
        "category": instance.category,
        "n_gaussians": instance.n_gaussians,
        "box": _box(instance),
    } | label


def write_ground_truth(
    folder: Path, scene: SyntheticScene, tasks: list[TaskSpec], outlier_views: list[dict] | None = None
) -> None:
    """Write gt.json and gt_gaussians.npz into folder; `outlier_views` (the dial's replaced frames,
    `outliers.OutlierView.to_json`) go in only when there are some, so other scenes' files keep
    their bytes."""
    by_id = {i.id: i for i in scene.instances}
    doc = {
        "format": FORMAT,
        "version": VERSION,
        "spec": scene.spec.ground_truth_dump(),
        "num_gaussians": int(len(scene.gaussians)),
        "gaussians_file": GT_ARRAYS,
        "instances": [_instance_json(i) for i in scene.instances],
        "tasks": [
            {
                "task": t.text,
                "granularity": t.granularity,
                "objects": [
                    {"instance_id": i, "name": by_id[i].name, "box": _box(by_id[i])} for i in t.instance_ids
                ],
            }
            for t in tasks
        ],
    }
    if outlier_views:
        doc["outlier_views"] = outlier_views
    (folder / GT_JSON).write_text(json.dumps(doc, indent=1))
    dtype = np.min_scalar_type(max(len(scene.instances) - 1, 0))
    np.savez_compressed(folder / GT_ARRAYS, instance_ids=scene.instance_ids.astype(dtype))


def _group_ids(instance_ids: np.ndarray, n: int) -> list[np.ndarray]:
    """Gaussian ids per instance 0..n-1 in one stable sort (no loop over Gaussians)."""
    order = np.argsort(instance_ids, kind="stable")
    counts = np.bincount(instance_ids, minlength=n)
    return np.split(order.astype(np.int64), np.cumsum(counts)[:-1])


def load_ground_truth(folder: str | Path) -> GroundTruth:
    """Read a synthetic scene's ground truth; InputError names the file and field on bad input."""
    folder = Path(folder)
    path = folder / GT_JSON
    try:
        doc = json.loads(path.read_text())
    except FileNotFoundError as exc:
        raise InputError("missing ground-truth file", source=str(path)) from exc
    except json.JSONDecodeError as exc:
        raise InputError(f"not valid JSON ({exc})", source=str(path)) from exc
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise InputError(f"field 'format' must be {FORMAT!r}", source=str(path))
    arrays = folder / doc.get("gaussians_file", GT_ARRAYS)
    try:
        with np.load(arrays, allow_pickle=False) as npz:
            ids = npz["instance_ids"].astype(np.int64)
    except (FileNotFoundError, KeyError, ValueError, OSError) as exc:
        raise InputError(f"cannot read array 'instance_ids' ({exc})", source=str(arrays)) from exc
    try:
        n_inst = len(doc["instances"])
        if (
            ids.ndim != 1
            or ids.size != doc["num_gaussians"]
            or (ids.size and (ids.min() < 0 or ids.max() >= n_inst))
        ):
            raise InputError(
                "instance_ids must be (num_gaussians,) with values in [0, len(instances))", source=str(arrays)
            )
        members = _group_ids(ids, n_inst)
        instances = [
            GTObject(
                instance_id=int(d["id"]),
                name=str(d["name"]),
                kind=str(d["kind"]),
                colour=d["colour"],
                category=str(d["category"]),
                center=np.asarray(d["box"]["center"], dtype=np.float64).reshape(3),
                rotation=np.asarray(d["box"]["rotation"], dtype=np.float64).reshape(3, 3),
                extents=np.asarray(d["box"]["extents"], dtype=np.float64).reshape(3),
                gaussian_ids=members[int(d["id"])],
            )
            for d in doc["instances"]
        ]
        tasks = [
            GTTask(
                str(t["task"]),
                str(t["granularity"]),
                [instances[int(o["instance_id"])] for o in t["objects"]],
            )
            for t in doc["tasks"]
        ]
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        if isinstance(exc, InputError):
            raise
        raise InputError(f"malformed ground truth ({type(exc).__name__}: {exc})", source=str(path)) from exc
    return GroundTruth(tasks=tasks, instances=instances, instance_ids=ids, spec=doc.get("spec", {}))
