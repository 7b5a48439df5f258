"""glTF / GLB with the `KHR_gaussian_splatting` extension, read with numpy.

The extension stores a point primitive whose attributes are POSITION (float VEC3),
`KHR_gaussian_splatting:ROTATION` (float VEC4, x y z w), `:SCALE` (float VEC3, linear),
`:OPACITY` (float SCALAR, linear), `:SH_DEGREE_<l>_COEF_<m>` (float VEC3 SH coefficients) and
COLOR_0 (a display colour, ignored when SH_DEGREE_0 is present). glTF is y-up; `splat-transform`
turns a 3DGS PLY 180 degrees about z on the way in (checked on its output: x and y change sign,
z does not), so we turn it back. Only `.glb` (one binary chunk) and `.gltf` with its buffer
embedded as a data URI or a file beside it are read; accessors must be tightly packed floats.
"""

from __future__ import annotations

import base64
import json
import struct
from pathlib import Path
from typing import Any

import numpy as np

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.scene.files import resolve_inside
from bayesian_fields_core.scene.formats.common import (
    colour_to_dc,
    gaussians,
    logit,
    require_count,
    rotate_axes,
    sh_from_bands,
)
from bayesian_fields_core.scene.types import Gaussians

EXTENSION = "KHR_gaussian_splatting"
GLTF_TO_PLY = np.diag([-1.0, -1.0, 1.0])
_COMPONENTS = {"SCALAR": 1, "VEC3": 3, "VEC4": 4}
_TYPES: dict[int, np.dtype] = {5126: np.dtype("<f4"), 5121: np.dtype("u1"), 5123: np.dtype("<u2")}


def _split_glb(raw: bytes, path: Path) -> tuple[dict[str, Any], bytes]:
    if len(raw) < 20 or raw[:4] != b"glTF":
        raise InputError("not a GLB file (bad magic)", source=str(path))
    json_len, json_type = struct.unpack_from("<II", raw, 12)
    if json_type != 0x4E4F534A or 20 + json_len > len(raw):
        raise InputError("GLB has no JSON chunk", source=str(path))
    doc = json.loads(raw[20 : 20 + json_len])
    offset = 20 + json_len
    binary = b""
    if offset + 8 <= len(raw):
        bin_len, bin_type = struct.unpack_from("<II", raw, offset)
        if bin_type == 0x004E4942:
            binary = raw[offset + 8 : offset + 8 + bin_len]
    return doc, binary


def _buffer(doc: dict[str, Any], index: int, glb_bin: bytes, path: Path) -> bytes:
    buffers = doc.get("buffers") or []
    if not 0 <= index < len(buffers):
        raise InputError(f"buffer {index} does not exist", source=str(path))
    uri = buffers[index].get("uri")
    if uri is None:
        return glb_bin
    if uri.startswith("data:"):
        return base64.b64decode(uri.split(",", 1)[1])
    return resolve_inside(path.parent, uri, what="glTF buffer", source=str(path)).read_bytes()


def _accessor(doc: dict[str, Any], index: int, glb_bin: bytes, path: Path, n: int) -> np.ndarray:
    try:
        acc = doc["accessors"][index]
        view = doc["bufferViews"][acc["bufferView"]]
        dtype = _TYPES[acc["componentType"]]
        width = _COMPONENTS[acc["type"]]
    except (KeyError, IndexError, TypeError):
        raise InputError(
            f"accessor {index} is malformed or of an unsupported type", source=str(path)
        ) from None
    if acc.get("count") != n:
        raise InputError(f"accessor {index} has {acc.get('count')} items, POSITION has {n}", source=str(path))
    stride = view.get("byteStride")
    if stride not in (None, dtype.itemsize * width):
        raise InputError(f"accessor {index} is interleaved; not supported", source=str(path))
    data = _buffer(doc, view.get("buffer", 0), glb_bin, path)
    start = int(view.get("byteOffset", 0)) + int(acc.get("byteOffset", 0))
    end = start + n * width * dtype.itemsize
    if end > len(data):
        raise InputError(f"accessor {index} runs past its buffer", source=str(path))
    values = np.frombuffer(data, dtype, n * width, start).reshape(n, width).astype(np.float32)
    if acc.get("normalized") and dtype.kind == "u":
        values /= float(np.iinfo(dtype).max)
    return values


def read_gltf(path: Path, max_gaussians: int) -> Gaussians:
    """Decode the first KHR_gaussian_splatting primitive of a .glb / .gltf into the PLY frame."""
    raw = path.read_bytes()
    try:
        doc, glb_bin = _split_glb(raw, path) if path.suffix.lower() == ".glb" else (json.loads(raw), b"")
    except (ValueError, UnicodeDecodeError) as exc:
        raise InputError(f"glTF JSON is not valid ({exc})", source=str(path)) from None
    prims = [
        p
        for mesh in doc.get("meshes", []) or []
        for p in mesh.get("primitives", []) or []
        if EXTENSION in (p.get("extensions") or {})
    ]
    if not prims:
        raise InputError(
            f"no primitive with the {EXTENSION} extension (a mesh, not a splat?)", source=str(path)
        )
    attrs = prims[0].get("attributes") or {}
    key = f"{EXTENSION}:"
    needed = ["POSITION", key + "ROTATION", key + "SCALE", key + "OPACITY"]
    missing = [a for a in needed if a not in attrs]
    if missing:
        raise InputError(f"splat primitive lacks {', '.join(missing)}", source=str(path))
    n = (doc.get("accessors") or [{}])[attrs["POSITION"]].get("count", 0)
    require_count(int(n), max_gaussians, source=path)

    def get(name: str) -> np.ndarray:
        return _accessor(doc, attrs[name], glb_bin, path, n)

    means, xyzw, scales, opacity = (get(a) for a in needed)
    if key + "SH_DEGREE_0_COEF_0" in attrs:
        dc = get(key + "SH_DEGREE_0_COEF_0")
    elif "COLOR_0" in attrs:
        dc = colour_to_dc(get("COLOR_0")[:, :3])
    else:
        raise InputError("splat primitive has neither SH_DEGREE_0_COEF_0 nor COLOR_0", source=str(path))
    bands = []
    for degree in (1, 2, 3):
        names = [f"{key}SH_DEGREE_{degree}_COEF_{m}" for m in range(2 * degree + 1)]
        if not all(name in attrs for name in names):
            break
        bands += [get(name) for name in names]
    rest = np.stack(bands, axis=1) if bands else None
    with np.errstate(divide="ignore"):
        log_scales = np.log(scales)
    g = gaussians(means, log_scales, xyzw[:, [3, 0, 1, 2]], logit(opacity[:, 0]), sh_from_bands(dc, rest))
    return rotate_axes(g, GLTF_TO_PLY)
