"""PlayCanvas / SuperSplat compressed PLY (`*.compressed.ply`), read with numpy.

Layout (what SuperSplat and `splat-transform` write): a `chunk` element, one row per 256
Gaussians, with the float bounds min/max_x,y,z and min/max_scale_x,y,z (optionally min/max_r,g,b);
a `vertex` element of four uint32 per Gaussian: packed_position and packed_scale (11/10/11 bits,
lerped between the chunk's bounds; scales are logs), packed_rotation (2 bits: index of the
largest quaternion component in rot_0..3 order, then the other three as 10-bit values in
[-1/sqrt2, 1/sqrt2]), packed_color (8 bits each of r, g, b lerped between the chunk's colour
bounds, and opacity); an optional `sh` element of uchar f_rest_* (channel-major like INRIA),
value = ((q + 0.5) / 256 - 0.5) * 8 (q = 0 reads as -4). Why our own: gsply reads it too but pays a numba
compilation of several seconds per process; this is a dozen vectorised lines.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.scene.formats.common import (
    colour_to_dc,
    gaussians,
    logit,
    require_count,
    sh_degree_for,
    sh_from_bands,
)
from bayesian_fields_core.scene.ply import read_ply_elements
from bayesian_fields_core.scene.types import Gaussians

CHUNK = 256
PACKED = ("packed_position", "packed_rotation", "packed_scale", "packed_color")


def is_compressed_ply(elements: list[tuple[str, int, list]]) -> bool:
    """A PLY whose vertex element holds the packed_* properties."""
    for name, _, props in elements:
        if name == "vertex":
            return {p[0] for p in props} >= set(PACKED)
    return False


def _unorm(value: np.ndarray, shift: int, bits: int) -> np.ndarray:
    return ((value >> np.uint32(shift)) & np.uint32((1 << bits) - 1)).astype(np.float32) / ((1 << bits) - 1)


def _unpack_111011(value: np.ndarray) -> np.ndarray:
    return np.stack([_unorm(value, 21, 11), _unorm(value, 11, 10), _unorm(value, 0, 11)], axis=1)


def _unpack_rotation(value: np.ndarray) -> np.ndarray:
    norm = np.float32(np.sqrt(2.0))  # components lie in [-1/sqrt2, 1/sqrt2]
    abc = np.stack([(_unorm(value, s, 10) - 0.5) * norm for s in (20, 10, 0)], axis=1)
    largest = (value >> np.uint32(30)).astype(np.int64)
    m = np.sqrt(np.clip(1.0 - (abc**2).sum(axis=1), 0.0, 1.0))
    quats = np.empty((value.shape[0], 4), np.float32)
    for i in range(4):
        rows = largest == i
        others = [j for j in range(4) if j != i]
        quats[np.ix_(rows, others)] = abc[rows]
        quats[rows, i] = m[rows]
    return quats


def _structured(path: Path, fmt: str, elements: list[tuple[str, int, list]], offset: int) -> dict:
    if fmt != "binary_little_endian":
        raise InputError(f"compressed PLY must be binary_little_endian, not {fmt}", source=str(path))
    tables = {}
    with open(path, "rb") as f:
        f.seek(offset)
        for name, count, props in elements:
            if any(p[1] == "list" for p in props):
                raise InputError(f"element {name!r} has list properties", source=str(path))
            dtype = np.dtype([(p[0], "<" + p[1]) for p in props])
            rows = np.fromfile(f, dtype=dtype, count=count)
            if rows.shape[0] != count:
                raise InputError(
                    f"truncated {name!r} data: expected {count} rows, got {rows.shape[0]}", source=str(path)
                )
            tables[name] = rows
    return tables


def read_compressed_ply(path: Path, max_gaussians: int) -> Gaussians:
    """Decode a compressed PLY into the INRIA parameterisation (see the module docstring)."""
    fmt, elements, offset = read_ply_elements(path)
    counts = {name: count for name, count, _ in elements}
    n = counts.get("vertex", 0)
    require_count(n, max_gaussians, source=path)
    if counts.get("chunk", -1) != (n + CHUNK - 1) // CHUNK:
        raise InputError(
            f"compressed PLY needs {(n + CHUNK - 1) // CHUNK} chunk rows for {n} vertices, "
            f"has {counts.get('chunk', 0)}",
            source=str(path),
        )
    for name, _, props in elements:
        if name == "vertex" and any(p[1] != "u4" for p in props if p[0] in PACKED):
            raise InputError("packed_* properties must be uint", source=str(path))
        if name == "chunk" and any(p[1] not in ("f4", "f8") for p in props):
            raise InputError("chunk properties must be float", source=str(path))
    tables = _structured(path, fmt, elements, offset)
    chunk, vertex = tables["chunk"], tables["vertex"]
    of = np.arange(n) // CHUNK

    def bounds(prefix: str, axes: tuple[str, str, str]) -> tuple[np.ndarray, np.ndarray]:
        lo = np.stack([chunk[f"min_{prefix}{a}"] for a in axes], axis=1).astype(np.float32)[of]
        hi = np.stack([chunk[f"max_{prefix}{a}"] for a in axes], axis=1).astype(np.float32)[of]
        return lo, hi

    names = set(chunk.dtype.names or ())
    need = {f"{m}_{a}" for m in ("min", "max") for a in "xyz"} | {
        f"{m}_scale_{a}" for m in ("min", "max") for a in "xyz"
    }
    if not need <= names:
        raise InputError(f"chunk element lacks {', '.join(sorted(need - names))}", source=str(path))
    lo, hi = bounds("", ("x", "y", "z"))
    means = lo + (hi - lo) * _unpack_111011(vertex["packed_position"])
    lo, hi = bounds("scale_", ("x", "y", "z"))
    log_scales = lo + (hi - lo) * _unpack_111011(vertex["packed_scale"])
    colour = vertex["packed_color"]
    rgb = np.stack([_unorm(colour, s, 8) for s in (24, 16, 8)], axis=1)
    if {"min_r", "max_r"} <= names:
        lo, hi = bounds("", ("r", "g", "b"))
        rgb = lo + (hi - lo) * rgb
    opacity = _unorm(colour, 0, 8)
    rest = None
    if "sh" in tables:
        sh_rows = tables["sh"]
        if sh_rows.shape[0] != n:
            raise InputError(f"sh element has {sh_rows.shape[0]} rows for {n} vertices", source=str(path))
        coeffs = len(sh_rows.dtype.names or ()) // 3
        sh_degree_for(coeffs, source=path)
        raw = np.stack([sh_rows[f"f_rest_{i}"] for i in range(coeffs * 3)], axis=1).astype(np.float32)
        values = (np.where(raw == 0, 0.0, raw + 0.5) / 256.0 - 0.5) * 8.0
        rest = values.reshape(n, 3, coeffs).transpose(0, 2, 1)
    return gaussians(
        means,
        log_scales,
        _unpack_rotation(vertex["packed_rotation"]),
        logit(opacity),
        sh_from_bands(colour_to_dc(rgb), rest),
    )
