"""INRIA 3DGS `cameras.json` (written next to a trained model) <-> Frames.

Each entry is {id, img_name, width, height, position, rotation, fx, fy}. In the 3DGS code
(`utils/camera_utils.py: camera_to_JSON`) `position` is the camera centre and `rotation` the
camera-to-world rotation (a list of rows), both in OpenCV camera axes; so world_to_camera has
rotation `R^T` and translation `-R^T position`. The principal point is not stored: 3DGS assumes
the image centre. `img_name` has no extension; we try the usual image extensions.
Frames keep file order (3DGS writes them sorted by image name within train/test).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bayesian_fields_core.errors import InputError, input_boundary
from bayesian_fields_core.geometry.transforms import (
    RIGID_TOLERANCE,
    intrinsics,
    invert_rigid,
    rigid,
    rotation_error,
)
from bayesian_fields_core.scene.files import load_json
from bayesian_fields_core.scene.images import resolve_image_path
from bayesian_fields_core.scene.types import Frame

REQUIRED_FIELDS = ("img_name", "width", "height", "position", "rotation", "fx", "fy")


def _entry_frame(entry: Any, where: str, images_dir: Path) -> Frame:
    if not isinstance(entry, dict):
        raise InputError("camera entry is not an object", source=where)
    missing = [k for k in REQUIRED_FIELDS if k not in entry]
    if missing:
        raise InputError(f"camera entry lacks {', '.join(missing)}", source=where)
    try:
        position = np.asarray(entry["position"], dtype=np.float64)
        rotation = np.asarray(entry["rotation"], dtype=np.float64)
        fx, fy = float(entry["fx"]), float(entry["fy"])
        width, height = int(entry["width"]), int(entry["height"])
    except (TypeError, ValueError, OverflowError) as exc:
        raise InputError(f"camera entry has non-numeric fields ({exc})", source=where) from exc
    if position.shape != (3,) or rotation.shape != (3, 3):
        raise InputError(
            f"position must be 3 numbers and rotation 3x3, got {position.shape} and {rotation.shape}",
            source=where,
        )
    if not (np.isfinite(position).all() and np.isfinite(rotation).all() and np.isfinite([fx, fy]).all()):
        raise InputError("non-finite position, rotation or focal length", source=where)
    if rotation_error(rotation) > RIGID_TOLERANCE:
        raise InputError("rotation is not a rotation matrix", source=where)
    if fx <= 0 or fy <= 0 or width <= 0 or height <= 0:
        raise InputError(f"invalid intrinsics fx={fx} fy={fy} width={width} height={height}", source=where)
    name = entry["img_name"]
    if not isinstance(name, str):
        raise InputError(f"img_name must be a string, got {type(name).__name__}", source=where)
    image_path = resolve_image_path(images_dir, name, source=where)  # containment checked first
    return Frame(
        name=name,
        K=intrinsics(fx, fy, width / 2.0, height / 2.0),
        world_to_camera=invert_rigid(rigid(rotation, position)),
        width=width,
        height=height,
        image_path=image_path,
    )


def read_cameras_json(path: str | Path, images_dir: str | Path | None = None) -> list[Frame]:
    """Frames of an INRIA cameras.json; images are looked up in `images_dir` (default: `images/`
    beside the file), and every img_name must stay inside it (`resolve_inside`)."""
    path = Path(path)
    with input_boundary(str(path), what="cannot read cameras.json"):
        return _read_cameras_json(path, images_dir)


def _read_cameras_json(path: Path, images_dir: str | Path | None) -> list[Frame]:
    doc = load_json(path)
    if not isinstance(doc, list) or not doc:
        raise InputError("expected a non-empty JSON list of cameras", source=str(path))
    root = Path(images_dir) if images_dir is not None else path.parent / "images"
    return [_entry_frame(entry, f"{path} [{i}]", root) for i, entry in enumerate(doc)]


def write_cameras_json(path: str | Path, frames: Sequence[Frame]) -> None:
    """Write frames as an INRIA cameras.json (pinhole, centred principal point only)."""
    path = Path(path)
    off_centre = [f.name for f in frames if not np.allclose(f.K[:2, 2], [f.width / 2.0, f.height / 2.0])]
    if off_centre:
        raise InputError(
            f"cameras.json cannot store an off-centre principal point ({off_centre[0]})", source=str(path)
        )
    distorted = [f.name for f in frames if f.distortion]
    if distorted:
        raise InputError(f"cameras.json cannot store lens distortion ({distorted[0]})", source=str(path))
    c2w = invert_rigid(np.stack([f.world_to_camera for f in frames]))
    doc = [
        {
            "id": i,
            "img_name": Path(f.name).stem,
            "width": int(f.width),
            "height": int(f.height),
            "position": pose[:3, 3].tolist(),
            "rotation": pose[:3, :3].tolist(),
            "fy": float(f.K[1, 1]),
            "fx": float(f.K[0, 0]),
        }
        for i, (f, pose) in enumerate(zip(frames, c2w, strict=True))
    ]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(doc, indent=2))
