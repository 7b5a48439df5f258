"""The splat-to-capture similarity of nerfstudio (splatfacto) and gsplat outputs, from their files.

nerfstudio (`ns-export gaussian-splat`, nerfstudio `scripts/exporter.py`) writes `model.means`,
`scales`, `quats` untouched, i.e. in the dataparser's internal frame. `dataparser_transforms.json`
(written by `save_dataparser_transform` next to the run's config) holds
`{"transform": 3x4 T, "scale": s}` with `x_internal = s * (T @ [x_original; 1])`, where *original*
is the dataparser's input frame *before* any `applied_transform` of the dataset:
- colmap dataparser: T = orient/centre @ applied_transform, original = the COLMAP world, which is
  the frame our COLMAP reader returns cameras in;
- nerfstudio dataparser (transforms.json): T = orient/centre @ applied_transform when the file has
  `applied_transform` (ns-process-data writes one), or the legacy colmap value when the dataset has
  `colmap/sparse/0` and no field; the poses in transforms.json are `applied_transform @ original`,
  so their frame is reached with applied_transform after T^-1. `applied_scale`, when present, is
  already folded into `scale` but not into the saved poses, so it is divided out.

gsplat (`examples/simple_trainer.py`, `normalize_world_space=True` by default) normalises cameras
and points with `parser.transform` (similarity_from_cameras, then PCA alignment and possibly a
180-degree flip; `examples/datasets/colmap.py`), a 4x4 similarity from the COLMAP world to the
splat's frame that gsplat does not save: the user writes it to a file (README recipe) as
`{"camera_to_splat": 4x4}`. The generic form `{"splat_to_camera": 4x4}` is accepted too.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.scene.files import load_json
from bayesian_fields_core.scene.similarity import Similarity

DATAPARSER_TRANSFORMS = "dataparser_transforms.json"
SPLAT_TRANSFORM = "splat_transform.json"
"""Generic transform file name looked up in the scene folder (`splat_to_camera` / `camera_to_splat`)."""

LEGACY_COLMAP_APPLIED_TRANSFORM = [[0.0, 1.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0]]
"""nerfstudio's implied applied_transform for transforms.json datasets made from COLMAP before the
field existed (nerfstudio_dataparser.py)."""


def _scale(value: Any, source: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not np.isfinite(value) or value <= 0:
        raise InputError(f"scale must be a positive finite number, got {value!r}", source=source)
    return float(value)


def read_transform_file(path: str | Path) -> tuple[Similarity, str]:
    """(camera-file-frame-independent similarity *splat -> original capture frame*, kind).

    Accepts a nerfstudio `dataparser_transforms.json` (kind 'nerfstudio'), or
    `{"camera_to_splat": 4x4}` (kind 'gsplat', gsplat's `parser.transform`), or
    `{"splat_to_camera": 4x4}` (kind 'matrix'). For nerfstudio the result maps to the
    dataparser's *original* frame; `nerfstudio_to_transforms_frame` adds the dataset's
    applied_transform for cameras read from transforms.json.
    """
    path = Path(path)
    doc = load_json(path)
    where = str(path)
    if not isinstance(doc, dict):
        raise InputError("expected a JSON object", source=where)
    keys = {"transform", "camera_to_splat", "splat_to_camera"} & set(doc)
    if len(keys) != 1:
        raise InputError(
            "expected exactly one of 'transform' + 'scale' (nerfstudio dataparser_transforms.json), "
            "'camera_to_splat' (gsplat parser.transform) or 'splat_to_camera' (4x4)",
            source=where,
        )
    key = keys.pop()
    if key == "transform":
        if "scale" not in doc:
            raise InputError("dataparser transform has no 'scale'", source=where)
        to_internal = Similarity.from_matrix(doc["transform"], source=f"{where} transform")
        if abs(to_internal.scale - 1.0) > 1e-4:
            raise InputError("dataparser 'transform' must be rigid (its scale is in 'scale')", source=where)
        scale = _scale(doc["scale"], f"{where} scale")
        internal = to_internal.then(Similarity(scale, np.eye(3), np.zeros(3)))
        return internal.inverse(), "nerfstudio"
    sim = Similarity.from_matrix(doc[key], source=f"{where} {key}")
    if key == "camera_to_splat":
        return sim.inverse(), "gsplat"
    return sim, "matrix"


def nerfstudio_to_transforms_frame(transforms_json: Path) -> tuple[Similarity, float]:
    """(applied_transform as a similarity original -> transforms.json frame, applied_scale).

    Identity when the dataset has neither the field nor the legacy `colmap/sparse/0`.
    """
    doc = load_json(transforms_json)
    where = str(transforms_json)
    applied: Any = doc.get("applied_transform") if isinstance(doc, dict) else None
    if applied is None and (transforms_json.parent / "colmap" / "sparse" / "0").is_dir():
        applied = LEGACY_COLMAP_APPLIED_TRANSFORM
    sim = (
        Similarity.identity()
        if applied is None
        else Similarity.from_matrix(applied, source=f"{where} applied_transform")
    )
    applied_scale = 1.0
    if isinstance(doc, dict) and "applied_scale" in doc:
        applied_scale = _scale(doc["applied_scale"], f"{where} applied_scale")
    return sim, applied_scale
