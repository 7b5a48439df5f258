"""Content keys for the task-independent caches: what a cached artifact was computed from.

A cached alignment verdict depends on the whole splat as drawn (colours too), every camera, the
photos of the frames it renders, its parameters and its own code. A cached perception frame depends
on the pixels the models see (the image file's bytes, plus the camera's K and distortion
coefficients when the loader undistorts) and on the models; a cached visibility frame adds the
Gaussians the renderer draws, the camera pose and intrinsics, and the depth settings. Paths, folder
names, modification times and task files are deliberately absent: moving or copying a scene,
editing its `tasks.yaml` or writing outputs into it must not invalidate anything (ARCHITECTURE,
"Caches are keyed on content").

Hashing: SHA-256 (hardware-accelerated on current x86 and ARM CPUs: about 3x BLAKE2b here) over
the whole file for images and depth maps (a few MB each), and over the
in-memory Gaussian arrays that visibility uses (positions, scales, rotations, opacities) rather
than the .ply bytes: that is the geometry after any frame transform a loader applied, and it
skips the SH colours, which are most of a splat's bytes and do not change depth (the alignment
key hashes them too: its check compares renders with photos).
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

import numpy as np

from bayesian_fields_core.scene.types import Frame, Gaussians

_HEX = 32  # 128 bits of the SHA-256: ample against accidental collisions, shorter keys


def _hasher() -> Any:
    return hashlib.sha256()


def file_digest(path: str | Path) -> str:
    """Hex digest of a file's size and bytes, streamed (never read whole into memory)."""
    with open(path, "rb") as fh:
        size = str(Path(path).stat().st_size).encode()
        h = hashlib.file_digest(fh, "sha256")
    return hashlib.sha256(size + h.digest()).hexdigest()[:_HEX]


def arrays_digest(*arrays: np.ndarray) -> str:
    """Hex digest of arrays' dtypes, shapes and bytes (C order; hashed without copying when contiguous)."""
    h = _hasher()
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(f"{a.dtype.str}{a.shape}".encode())
        h.update(a.data.cast("B"))
    return h.hexdigest()[:_HEX]


def object_digest(obj: Any) -> str:
    """Hex digest of a JSON-able description (sorted keys; floats as Python writes them)."""
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()[:_HEX]


def splat_digest(gaussians: Gaussians) -> str:
    """Digest of what depth rendering and association read: means (N, 3), log_scales (N, 3),
    quats (N, 4), opacity_logits (N,)."""
    g = gaussians
    return arrays_digest(g.means, g.log_scales, g.quats, g.opacity_logits)


def perception_input_digest(frame: Frame) -> str:
    """What `load_image(frame)` returns depends on: the image bytes, the size it is checked
    against, and K + distortion when the loader resamples a distorted image into K."""
    if frame.image_path is None:
        raise ValueError(f"frame {frame.name} has no image")
    desc: dict[str, Any] = {
        "image": file_digest(frame.image_path),
        "size": [int(frame.width), int(frame.height)],
    }
    if frame.distortion:
        desc["K"] = np.asarray(frame.K, dtype=np.float64).round(9).tolist()
        desc["distortion"] = frame.distortion
    return object_digest(desc)


def visibility_input_digest(perception_key: str, splat: str, frame: Frame, depth: dict[str, Any]) -> str:
    """Digest of one frame's mask-to-Gaussian associations' inputs.

    perception_key: the frame's perception cache key (labels come from it). splat: `splat_digest`.
    depth: the parameters `stage_table.VISIBILITY_CACHE` names, by field; with depth_source 'input' the depth file's
    digest and scale are added here.
    """
    desc = {
        "perception": perception_key,
        "splat": splat,
        "K": np.asarray(frame.K, dtype=np.float64).round(9).tolist(),
        "world_to_camera": np.asarray(frame.world_to_camera, dtype=np.float64).round(9).tolist(),
        "size": [int(frame.width), int(frame.height)],
        "depth": depth,
    }
    if depth.get("depth_source") == "input" and frame.depth_path is not None:
        desc["depth_file"] = file_digest(frame.depth_path)
        desc["depth_scale"] = float(frame.depth_scale)
    return object_digest(desc)


def alignment_input_digest(
    splat: str,
    colours: str,
    frames: list[Frame],
    images: list[str],
    parameters: dict[str, Any],
    code: str,
) -> str:
    """Digest of what the alignment check's report depends on.

    splat: `splat_digest`; colours: digest of the SH coefficients (the rendered part compares
    colours). frames: every camera (the geometric part samples up to 200 and the camera baseline
    spans all; the report names frames). images: `perception_input_digest` of each frame the
    rendered part compares, in its order. parameters: `stage_table.ALIGNMENT_CACHE.params` by field
    (a scale derived from the scene follows from the splat and cameras above). code: fingerprint
    of the check's source (`checks.alignment.code_fingerprint`).
    """
    cameras = [
        {
            "name": f.name,
            "K": np.asarray(f.K, dtype=np.float64).round(9).tolist(),
            "world_to_camera": np.asarray(f.world_to_camera, dtype=np.float64).round(9).tolist(),
            "size": [int(f.width), int(f.height)],
            "distortion": f.distortion,
        }
        for f in frames
    ]
    return object_digest(
        {
            "splat": splat,
            "colours": colours,
            "cameras": cameras,
            "images": images,
            "parameters": parameters,
            "code": code,
        }
    )
