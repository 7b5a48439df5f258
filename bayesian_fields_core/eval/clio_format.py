"""Clio's dataset files: the task ground truth (`tasks_<scene>.yaml`) and `scene_transforms.yaml`.

Facts about Clio's layout (MIT-SPARK/Clio, README and `clio_eval/`), so a user who has the Clio
datasets can run Table 1 on them:

- The ground truth is a YAML mapping of task text to a list of boxes, each
  `{center: [x, y, z], extents: [a, b, c], rotation: ...}`, `extents` the *full* side lengths,
  `rotation` a quaternion as a mapping `{w, x, y, z}` or a list `[w, x, y, z]` (w first). The boxes
  are in the dataset's metric world frame. A task with an empty list has no relevant object.
- `clio_eval/scene_transforms.yaml` is keyed by scene name (`apartment`, `office`, `cubicle`,
  `old_office`), each with a 4x4 rigid `T` and a `scale`. It maps the COLMAP reconstruction into
  the ground truth's frame: Clio's viewer draws the COLMAP mesh as `mesh.scale(scale, origin)`
  then `.transform(T)`, i.e. `x_gt = R (scale x_colmap) + t`.

A splat trained on Clio's COLMAP poses lives in the COLMAP frame (our cameras', or *capture*,
frame), so the transform maps our boxes to the GT's frame. We map the GT boxes the other way
(the inverse similarity) into the capture frame instead: Clio's metrics (IoU, centroid
containment) are invariant under a similarity, so the scores are the same either way.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.eval.clio import GTObject
from bayesian_fields_core.geometry.obb import OrientedBox
from bayesian_fields_core.job.task_list import normalise_tasks
from bayesian_fields_core.scene.similarity import Similarity

MAX_FILE_BYTES = 16 * 1024 * 1024
"""A ground-truth or transform file larger than this is refused (Clio's are a few kB)."""


@dataclass(frozen=True)
class ClioGroundTruth:
    """Tasks in file order (absent ones, with an empty box list, included) and their GT objects."""

    tasks: list[str]
    objects: list[GTObject]

    @property
    def absent_tasks(self) -> list[str]:
        present = {g.task for g in self.objects}
        return [t for t in self.tasks if t not in present]

    def mapped(self, transform: Similarity) -> ClioGroundTruth:
        """The same ground truth with every box mapped by `transform`."""
        return ClioGroundTruth(
            list(self.tasks), [GTObject(task=g.task, box=transform.box(g.box)) for g in self.objects]
        )


def _read_yaml(path: Path) -> Any:
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise InputError(f"cannot read: {exc.strerror or exc}", source=str(path)) from None
    if size > MAX_FILE_BYTES:
        raise InputError(f"file is {size} bytes, more than the {MAX_FILE_BYTES} allowed", source=str(path))
    try:
        return yaml.safe_load(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError:
        raise InputError("not UTF-8 text", source=str(path)) from None
    except yaml.YAMLError as exc:
        first = " ".join(str(exc).split())
        raise InputError(f"cannot parse YAML: {first}", source=str(path)) from None


def _finite_vector(value: Any, n: int, what: str) -> np.ndarray:
    """(n,) float64 from a list of n real numbers (no bools, strings or non-finite values)."""
    if not isinstance(value, list | tuple) or len(value) != n:
        raise InputError(f"{what} must be a list of {n} numbers, got {_describe(value)}")
    if any(isinstance(v, bool) or not isinstance(v, int | float) for v in value):
        raise InputError(f"{what} must hold numbers only, got {list(value)!r}")
    out = np.asarray(value, dtype=np.float64)
    if not np.isfinite(out).all():
        raise InputError(f"{what} must be finite, got {out.tolist()}")
    return out


def _describe(value: Any) -> str:
    if isinstance(value, list | tuple):
        return f"a list of {len(value)}"
    return type(value).__name__


def quaternion_matrix(rotation: Any) -> np.ndarray:
    """(3, 3) rotation of a Clio quaternion: `{w, x, y, z}` or `[w, x, y, z]` (w first), any
    non-zero norm (normalised here, as scipy does in Clio's code)."""
    if isinstance(rotation, Mapping):
        keys = set(rotation)
        if keys != {"w", "x", "y", "z"}:
            raise InputError(f"rotation mapping must have keys w, x, y, z, got {sorted(map(str, keys))}")
        wxyz = _finite_vector([rotation[k] for k in "wxyz"], 4, "rotation")
    elif isinstance(rotation, list | tuple):
        if len(rotation) != 4:
            raise InputError(f"rotation must be a quaternion [w, x, y, z], got {_describe(rotation)}")
        wxyz = _finite_vector(rotation, 4, "rotation")
    else:
        raise InputError(
            f"rotation must be a quaternion {{w, x, y, z}} or [w, x, y, z], got {_describe(rotation)}"
        )
    norm = float(np.linalg.norm(wxyz))
    if norm < 1e-9:
        raise InputError("rotation quaternion has zero norm")
    w, x, y, z = wxyz / norm
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def parse_clio_ground_truth(data: Any, *, source: str) -> ClioGroundTruth:
    """Validate a parsed Clio task YAML; InputError names the file, the task and the box."""
    if not isinstance(data, Mapping) or not data:
        raise InputError("expected a non-empty mapping of task -> list of boxes", source=source)
    # The task texts go to the pipeline: the same rules as a task file (text, unique, bounded),
    # and the same whitespace normalisation, so GT and answers are keyed alike.
    tasks = normalise_tasks(list(data.keys()), source=source)
    objects: list[GTObject] = []
    for task, boxes in zip(tasks, data.values(), strict=True):
        if boxes is None:
            boxes = []
        if not isinstance(boxes, list):
            raise InputError(
                f"task {task!r}: expected a list of boxes, got {_describe(boxes)}", source=source
            )
        for i, entry in enumerate(boxes):
            where = f"task {task!r} box {i}"
            try:
                if not isinstance(entry, Mapping):
                    raise InputError(
                        f"expected a mapping with center, extents, rotation, got {_describe(entry)}"
                    )
                missing = [k for k in ("center", "extents", "rotation") if k not in entry]
                if missing:
                    raise InputError(f"missing field {missing[0]!r}")
                center = _finite_vector(entry["center"], 3, "center")
                extents = _finite_vector(entry["extents"], 3, "extents")
                if (extents <= 0).any():
                    raise InputError(f"extents must be positive, got {extents.tolist()}")
                box = OrientedBox(center, quaternion_matrix(entry["rotation"]), extents)
            except InputError as exc:
                raise InputError(f"{where}: {exc}", source=source) from None
            objects.append(GTObject(task=task, box=box))
    if not objects:
        raise InputError("no task has a ground-truth box", source=source)
    return ClioGroundTruth(tasks, objects)


def read_clio_ground_truth(path: str | Path) -> ClioGroundTruth:
    """Read and validate a Clio task YAML (`tasks_<scene>.yaml`)."""
    path = Path(path)
    return parse_clio_ground_truth(_read_yaml(path), source=str(path))


def parse_scene_transform(
    data: Any, *, source: str, key: str | None = None, default_key: str | None = None
) -> Similarity:
    """The COLMAP -> GT similarity `x -> R (scale x) + t` from a parsed transform file.

    The file is either one entry `{T: 4x4, scale: s}` or Clio's `scene_transforms.yaml`, a mapping
    of scene name to such entries; then `key` names the scene, else `default_key` (the scene
    folder's name, as Clio's folders are named) when the file has it, else the only entry."""
    if not isinstance(data, Mapping):
        raise InputError("expected a mapping with T and scale, or scene name -> {T, scale}", source=source)
    if "T" in data:
        entry, where = data, ""
    else:
        names = [str(k) for k in data]
        if key is None and default_key in names:
            key = default_key
        if key is None:
            if len(names) != 1:
                raise InputError(
                    f"several scenes ({', '.join(names)}): choose one with --transform-key", source=source
                )
            key = names[0]
        if key not in data:
            raise InputError(f"no scene {key!r} (have: {', '.join(names) or 'none'})", source=source)
        entry, where = data[key], f"{key}: "
    if not isinstance(entry, Mapping) or "T" not in entry or "scale" not in entry:
        raise InputError(f"{where}expected fields T (4x4) and scale", source=source)
    rows = entry["T"]
    if (
        not isinstance(rows, list)
        or len(rows) != 4
        or any(not isinstance(r, list) or len(r) != 4 for r in rows)
    ):
        raise InputError(f"{where}T must be a 4x4 list of rows", source=source)
    try:
        matrix = np.stack([_finite_vector(r, 4, "T row") for r in rows])
        scale = entry["scale"]
        if (
            isinstance(scale, bool)
            or not isinstance(scale, int | float)
            or not np.isfinite(scale)
            or scale <= 0
        ):
            raise InputError(f"scale must be a finite number > 0, got {scale!r}")
    except InputError as exc:
        raise InputError(f"{where}{exc}", source=source) from None
    rigid = Similarity.from_matrix(matrix, source=f"{source}: {where}T")
    if abs(rigid.scale - 1.0) > 1e-3:
        raise InputError(
            f"{where}T must be rigid (its 3x3 block a rotation); put the scale in 'scale'", source=source
        )
    return Similarity(float(scale), rigid.rotation, rigid.translation)


def read_scene_transform(
    path: str | Path, key: str | None = None, default_key: str | None = None
) -> Similarity:
    """Read and validate a transform file (see `parse_scene_transform`)."""
    path = Path(path)
    return parse_scene_transform(_read_yaml(path), source=str(path), key=key, default_key=default_key)


def load_clio_case(
    gt_file: str | Path,
    transform_file: str | Path | None = None,
    key: str | None = None,
    default_key: str | None = None,
) -> ClioGroundTruth:
    """Clio's ground truth mapped into the scene's capture (COLMAP) frame: with a transform
    (COLMAP -> GT), its inverse is applied to every GT box; without one, the boxes are used as is."""
    gt = read_clio_ground_truth(gt_file)
    if transform_file is None:
        return gt
    return gt.mapped(read_scene_transform(transform_file, key, default_key).inverse())
