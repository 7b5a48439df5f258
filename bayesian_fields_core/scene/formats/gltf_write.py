"""Write a splat as a binary glTF (`.glb`) with the `KHR_gaussian_splatting` extension.

No Python library writes this format, so it is written here from the glTF 2.0 specification
(GLB container: 12-byte header, a JSON chunk padded with spaces and a BIN chunk padded with
zeros, each to 4 bytes) and the extension's attribute set, laid out as `splat-transform` lays out
its own `.glb` (tests/fixtures/formats/tabletop.glb): one POINTS primitive whose attributes are
POSITION (float VEC3, with the min / max glTF requires), COLOR_0 (normalised unsigned byte VEC4:
the degree-0 colour and the opacity, for viewers without the extension),
`KHR_gaussian_splatting:ROTATION` (float VEC4, x y z w, unit length), `:SCALE` (float VEC3,
linear), `:OPACITY` (float SCALAR, linear) and `:SH_DEGREE_<l>_COEF_<m>` (float VEC3, the SH
coefficients as in the PLY), each in its own tightly packed buffer view. glTF is y-up: the
Gaussians are turned 180 degrees about z, the inverse of what `gltf.read_gltf` undoes.
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np

from bayesian_fields_core.geometry.spherical_harmonics import SH_C0
from bayesian_fields_core.scene.formats.common import rotate_axes
from bayesian_fields_core.scene.formats.gltf import BIN_CHUNK, EXTENSION, GLTF_TO_PLY, JSON_CHUNK
from bayesian_fields_core.scene.types import Gaussians

GLB_MAGIC, GLB_VERSION = 0x46546C67, 2  # "glTF", container version 2
FLOAT, UNSIGNED_BYTE = 5126, 5121
ARRAY_BUFFER = 34962
POINTS = 0
PRIMITIVE_EXTENSION = {
    "kernel": "ellipse",
    "colorSpace": "srgb_rec709_display",
    "sortingMethod": "cameraDistance",
    "projection": "perspective",
}
"""The extension's primitive properties, as splat-transform writes them (3DGS's own rendering)."""


def _columns(g: Gaussians) -> list[tuple[str, np.ndarray, str, bool]]:
    """(attribute, C-contiguous little-endian array, accessor type, normalised) in file order."""
    quats = np.asarray(g.quats, dtype=np.float64)
    quats = quats / np.linalg.norm(quats, axis=1, keepdims=True)
    colour = np.clip(0.5 + SH_C0 * np.asarray(g.sh[:, 0, :], dtype=np.float64), 0.0, 1.0)
    rgba = np.round(np.column_stack([colour, np.clip(g.opacities, 0.0, 1.0)]) * 255.0).astype(np.uint8)
    key = f"{EXTENSION}:"
    columns = [
        ("POSITION", g.means, "VEC3", False),
        ("COLOR_0", rgba, "VEC4", True),
        (key + "ROTATION", quats[:, [1, 2, 3, 0]], "VEC4", False),
        (key + "SCALE", np.exp(np.asarray(g.log_scales, dtype=np.float64)), "VEC3", False),
        (key + "OPACITY", g.opacities, "SCALAR", False),
    ]
    for degree in range(g.sh_degree + 1):
        for m in range(2 * degree + 1):
            columns.append(
                (f"{key}SH_DEGREE_{degree}_COEF_{m}", g.sh[:, degree * degree + m, :], "VEC3", False)
            )
    return [
        (name, np.ascontiguousarray(a, dtype="<f4" if a.dtype.kind == "f" else "u1"), kind, norm)
        for name, a, kind, norm in columns
    ]


def _padded(data: bytes, fill: bytes) -> bytes:
    return data + fill * (-len(data) % 4)


def write_glb(path: str | Path, gaussians: Gaussians) -> None:
    """Write `gaussians` (a 3DGS PLY's frame and parameterisation) as a `.glb` (module docstring)."""
    g = rotate_axes(gaussians, GLTF_TO_PLY)  # 180 degrees about z: its own inverse
    n = len(g)
    accessors, views, attributes, blobs = [], [], {}, []
    offset = 0
    for index, (name, array, kind, normalised) in enumerate(_columns(g)):
        data = array.tobytes()
        views.append({"buffer": 0, "byteOffset": offset, "byteLength": len(data), "target": ARRAY_BUFFER})
        accessor = {
            "bufferView": index,
            "byteOffset": 0,
            "componentType": UNSIGNED_BYTE if array.dtype.kind == "u" else FLOAT,
            "count": n,
            "type": kind,
        }
        if normalised:
            accessor["normalized"] = True
        if name == "POSITION":
            accessor["min"] = array.min(axis=0).astype(float).tolist()
            accessor["max"] = array.max(axis=0).astype(float).tolist()
        accessors.append(accessor)
        attributes[name] = index
        blobs.append(_padded(data, b"\0"))
        offset += len(blobs[-1])
    document = {
        "asset": {"version": "2.0", "generator": "bayesian-fields"},
        "extensionsUsed": [EXTENSION],
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [
            {
                "primitives": [
                    {"attributes": attributes, "mode": POINTS, "extensions": {EXTENSION: PRIMITIVE_EXTENSION}}
                ]
            }
        ],
        "buffers": [{"byteLength": offset}],
        "bufferViews": views,
        "accessors": accessors,
    }
    text = _padded(json.dumps(document, separators=(",", ":")).encode("utf-8"), b" ")
    binary = b"".join(blobs)
    total = 12 + 8 + len(text) + 8 + len(binary)
    with open(path, "wb") as f:
        f.write(struct.pack("<III", GLB_MAGIC, GLB_VERSION, total))
        f.write(struct.pack("<II", len(text), JSON_CHUNK) + text)
        f.write(struct.pack("<II", len(binary), BIN_CHUNK) + binary)
