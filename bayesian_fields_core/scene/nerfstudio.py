"""nerfstudio / Instant-NGP / Blender `transforms.json` <-> Frames.

`transform_matrix` is camera-to-world in the OpenGL camera axes (x right, y up, z back); flipping
the y and z camera axes gives the OpenCV camera-to-world, whose rigid inverse is the Frame's
world_to_camera. Intrinsics may be shared (top level) or per frame (per-frame keys win). When
`fl_x` is missing, the NeRF-synthetic `camera_angle_x` (horizontal field of view) gives it; when
`w`/`h` are missing (Blender files), the image header gives the size. Frames keep file order.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from bayesian_fields_core.errors import InputError, input_boundary
from bayesian_fields_core.geometry.transforms import (
    OPENGL_TO_OPENCV,
    RIGID_TOLERANCE,
    intrinsics,
    invert_rigid,
    rotation_error,
)
from bayesian_fields_core.scene.files import load_json, resolve_inside
from bayesian_fields_core.scene.images import DISTORTION_KEYS, clean_distortion, resolve_image_path
from bayesian_fields_core.scene.types import Frame

PINHOLE_CAMERA_MODELS = ("OPENCV", "PINHOLE", "SIMPLE_PINHOLE")
"""nerfstudio `camera_model` values whose k1..p2 coefficients we can undistort."""

MASK_PATH_KEYS = ("mask_path", "mask_file_path")
"""Per-frame mask keys nerfstudio datasets use; checked for containment though not loaded."""

DEFAULT_DEPTH_UNIT_SCALE = 1e-3
"""Metres per depth-image unit when `depth_unit_scale_factor` is absent (nerfstudio's default)."""


def _number(entry: dict, top: dict, key: str, where: str) -> float | None:
    value = entry.get(key, top.get(key))
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise InputError(f"{key} must be a finite number, got {value!r}", source=where)
    return float(value)


def _image_size(path: Path, where: str) -> tuple[int, int]:
    try:
        with Image.open(path) as img:
            return img.width, img.height
    except (OSError, ValueError) as exc:
        raise InputError(
            f"w/h missing and the image size cannot be read from {path} ({exc})", source=where
        ) from exc


def _field_of_view(angle: float, key: str, where: str) -> float:
    """A field of view in radians strictly between 0 and pi (else the focal length is 0 or inf)."""
    if not 0.0 < angle < math.pi:
        raise InputError(f"{key}={angle} is not a field of view in (0, pi) radians", source=where)
    return angle


def _path_field(entry: dict, key: str, root: Path, where: str) -> Path | None:
    """The entry's `key` path resolved inside `root`, None when absent; refused when it escapes."""
    value = entry.get(key)
    if value is None:
        return None
    if not isinstance(value, str):
        raise InputError(f"{key} must be a string, got {type(value).__name__}", source=where)
    return resolve_inside(root, value, what=key, source=where)


def _frame_camera(
    entry: dict, top: dict, image_path: Path, where: str
) -> tuple[np.ndarray, int, int, dict[str, float] | None]:
    """(K, width, height, distortion) of one frame from its keys over the top-level ones."""
    model = entry.get("camera_model", top.get("camera_model", "OPENCV"))
    if model not in PINHOLE_CAMERA_MODELS:
        raise InputError(
            f"unsupported camera_model {model!r} (supported: {', '.join(PINHOLE_CAMERA_MODELS)})",
            source=where,
        )
    w, h = _number(entry, top, "w", where), _number(entry, top, "h", where)
    if w is None or h is None:
        w, h = _image_size(image_path, where)
    fx = _number(entry, top, "fl_x", where)
    fy = _number(entry, top, "fl_y", where)
    if fx is None:
        angle_x = _number(entry, top, "camera_angle_x", where)
        if angle_x is None:
            raise InputError("no intrinsics: neither fl_x nor camera_angle_x is given", source=where)
        fx = 0.5 * w / math.tan(0.5 * _field_of_view(angle_x, "camera_angle_x", where))
    if fy is None:
        angle_y = _number(entry, top, "camera_angle_y", where)
        fy = (
            0.5 * h / math.tan(0.5 * _field_of_view(angle_y, "camera_angle_y", where))
            if angle_y is not None
            else fx
        )
    cx = _number(entry, top, "cx", where)
    cy = _number(entry, top, "cy", where)
    cx = w / 2.0 if cx is None else cx
    cy = h / 2.0 if cy is None else cy
    if not (0 < fx < math.inf and 0 < fy < math.inf) or w <= 0 or h <= 0 or w != int(w) or h != int(h):
        raise InputError(f"invalid intrinsics fl_x={fx} fl_y={fy} w={w} h={h}", source=where)
    coeffs = {k: v for k in DISTORTION_KEYS if (v := _number(entry, top, k, where)) is not None}
    if (k4 := _number(entry, top, "k4", where)) not in (None, 0.0):
        raise InputError(f"k4={k4} is a fisheye coefficient; unsupported", source=where)
    return intrinsics(fx, fy, cx, cy), int(w), int(h), clean_distortion(coeffs, source=where)


def _pose(entry: dict, where: str) -> np.ndarray:
    try:
        c2w = np.asarray(entry["transform_matrix"], dtype=np.float64)
    except KeyError as exc:
        raise InputError("frame has no transform_matrix", source=where) from exc
    except (TypeError, ValueError) as exc:
        raise InputError("transform_matrix is not a numeric matrix", source=where) from exc
    if c2w.shape == (3, 4):
        c2w = np.vstack([c2w, [0.0, 0.0, 0.0, 1.0]])
    if c2w.shape != (4, 4) or not np.isfinite(c2w).all():
        raise InputError(
            f"transform_matrix must be a finite 4x4 (or 3x4) matrix, got shape {c2w.shape}", source=where
        )
    if rotation_error(c2w[:3, :3]) > RIGID_TOLERANCE:
        raise InputError(
            "transform_matrix is not a rigid transform (its rotation part is not orthonormal)", source=where
        )
    return invert_rigid(c2w @ OPENGL_TO_OPENCV)


def read_transforms(path: str | Path) -> list[Frame]:
    """Frames of a transforms.json; image, depth and mask paths are relative to the file's folder
    and must stay inside it (`resolve_inside`). Any parse failure is an InputError."""
    path = Path(path)
    with input_boundary(str(path), what="cannot read transforms.json"):
        return _read_transforms(path)


def _read_transforms(path: Path) -> list[Frame]:
    doc = load_json(path)
    if not isinstance(doc, dict):
        raise InputError("top level must be a JSON object", source=str(path))
    entries = doc.get("frames")
    if not isinstance(entries, list) or not entries:
        raise InputError("no 'frames' list (or it is empty)", source=str(path))
    root = path.parent
    depth_scale = _number({}, doc, "depth_unit_scale_factor", str(path))
    frames = []
    for i, entry in enumerate(entries):
        where = f"{path} frames[{i}]"
        if not isinstance(entry, dict) or not isinstance(entry.get("file_path"), str):
            raise InputError("frame has no file_path string", source=where)
        # Every path is checked for containment before anything is opened (image size, depth).
        image_path = resolve_image_path(root, entry["file_path"], source=where)
        depth_path = _path_field(entry, "depth_file_path", root, where)
        for key in MASK_PATH_KEYS:  # not read by this loader, but never allowed to point outside
            _path_field(entry, key, root, where)
        K, w, h, dist = _frame_camera(entry, doc, image_path, where)
        frames.append(
            Frame(
                name=entry["file_path"],
                K=K,
                world_to_camera=_pose(entry, where),
                width=w,
                height=h,
                image_path=image_path,
                depth_path=depth_path,
                depth_scale=depth_scale if depth_scale is not None else DEFAULT_DEPTH_UNIT_SCALE,
                distortion=dist,
            )
        )
    return frames


def _relative(target: Path | None, root: Path, fallback: str) -> str:
    if target is None:
        return fallback
    try:
        return Path(os.path.relpath(target, root)).as_posix()
    except ValueError:  # different drives on Windows
        return str(target)


def write_transforms(path: str | Path, frames: Sequence[Frame]) -> None:
    """Write a transforms.json with per-frame intrinsics and OpenGL camera-to-world matrices.

    Depth scale is written once at the top (`depth_unit_scale_factor`), so the frames given must
    share it when they have depth.
    """
    path = Path(path)
    scales = {f.depth_scale for f in frames if f.depth_path is not None}
    if len(scales) > 1:
        raise InputError(f"frames with depth use different depth scales {sorted(scales)}", source=str(path))
    c2w = invert_rigid(np.stack([f.world_to_camera for f in frames])) @ OPENGL_TO_OPENCV
    entries = []
    for frame, pose in zip(frames, c2w, strict=True):
        K = frame.K
        entry: dict[str, Any] = {
            "file_path": _relative(frame.image_path, path.parent, frame.name),
            "fl_x": float(K[0, 0]),
            "fl_y": float(K[1, 1]),
            "cx": float(K[0, 2]),
            "cy": float(K[1, 2]),
            "w": int(frame.width),
            "h": int(frame.height),
            "transform_matrix": pose.tolist(),
        }
        entry.update({k: float(v) for k, v in (frame.distortion or {}).items()})
        if frame.depth_path is not None:
            entry["depth_file_path"] = _relative(frame.depth_path, path.parent, str(frame.depth_path))
        entries.append(entry)
    doc: dict[str, Any] = {"camera_model": "OPENCV", "frames": entries}
    if scales:
        doc["depth_unit_scale_factor"] = scales.pop()
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(doc, indent=2))
