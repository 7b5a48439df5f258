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
from bayesian_fields_core.scene.formats.ply_tables import element_tables
from bayesian_fields_core.scene.formats.source import SplatSource
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


CHUNK_BOUNDS = tuple(f"{m}_{a}" for m in ("min", "max") for a in "xyz") + tuple(
    f"{m}_scale_{a}" for m in ("min", "max") for a in "xyz"
)
COLOUR_BOUNDS = tuple(f"{m}_{c}" for m in ("min", "max") for c in "rgb")


class CompressedPlySource(SplatSource):
    """An opened compressed PLY: header, chunk bounds and body size checked, rows read by range.

    The chunk table (one row per 256 Gaussians, 72 bytes or so) is read whole and checked
    (finite, min <= max); vertex and SH rows are read per range."""

    def __init__(self, path: Path, max_gaussians: int) -> None:
        fmt, elements, offset = read_ply_elements(path)
        counts = {name: count for name, count, _ in elements}
        n = counts.get("vertex", 0)
        require_count(n, max_gaussians, source=path)
        chunks = (n + CHUNK - 1) // CHUNK
        if counts.get("chunk", -1) != chunks:
            raise InputError(
                f"compressed PLY needs {chunks} chunk rows for {n} vertices, has {counts.get('chunk', 0)}",
                source=str(path),
            )
        if "sh" in counts and counts["sh"] != n:
            raise InputError(f"sh element has {counts['sh']} rows for {n} vertices", source=str(path))
        for name, _, props in elements:
            if name == "vertex" and any(p[1] != "u4" for p in props if p[0] in PACKED):
                raise InputError("packed_* properties must be uint", source=str(path))
            if name == "chunk" and any(p[1] not in ("f4", "f8") for p in props):
                raise InputError("chunk properties must be float", source=str(path))
            if name == "sh" and any(p[1] != "u1" for p in props):
                raise InputError("sh properties must be uchar", source=str(path))
        self._file = open(path, "rb")  # noqa: SIM115 - closed by close()
        try:
            if fmt != "binary_little_endian":
                raise InputError(f"compressed PLY must be binary_little_endian, not {fmt}", source=str(path))
            tables = element_tables(self._file, path, fmt, elements, offset, formats="compressed PLY")
            self._vertex = tables["vertex"]
            self._sh = tables.get("sh")
            self._chunk = _checked_chunks(path, tables["chunk"].read(0, chunks))
            coeffs = 0
            if self._sh is not None:
                names = self._sh.dtype.names or ()
                coeffs = len(names) // 3
                want = [f"f_rest_{i}" for i in range(coeffs * 3)]
                if list(names) != want:
                    raise InputError(
                        f"sh properties must be f_rest_0..f_rest_{len(names) - 1}", source=str(path)
                    )
            degree = sh_degree_for(coeffs, source=path)
        except BaseException:
            self._file.close()
            raise
        super().__init__(path, n, degree)

    def rows(self, start: int, stop: int) -> Gaussians:
        vertex = self._vertex.read(start, stop)
        n = vertex.shape[0]
        of = np.arange(start, start + n) // CHUNK
        chunk = self._chunk

        def lerp(prefix: str, axes: tuple[str, str, str], unit: np.ndarray) -> np.ndarray:
            lo = np.stack([chunk[f"min_{prefix}{a}"] for a in axes], axis=1).astype(np.float32)[of]
            hi = np.stack([chunk[f"max_{prefix}{a}"] for a in axes], axis=1).astype(np.float32)[of]
            return lo + (hi - lo) * unit

        means = lerp("", ("x", "y", "z"), _unpack_111011(vertex["packed_position"]))
        log_scales = lerp("scale_", ("x", "y", "z"), _unpack_111011(vertex["packed_scale"]))
        colour = vertex["packed_color"]
        rgb = np.stack([_unorm(colour, s, 8) for s in (24, 16, 8)], axis=1)
        if set(COLOUR_BOUNDS) <= set(chunk.dtype.names or ()):
            rgb = lerp("", ("r", "g", "b"), rgb)
        rest = None
        if self._sh is not None and self.sh_degree > 0:
            sh_rows = self._sh.read(start, stop)
            coeffs = len(sh_rows.dtype.names or ()) // 3
            raw = np.stack([sh_rows[f"f_rest_{i}"] for i in range(coeffs * 3)], axis=1).astype(np.float32)
            values = (np.where(raw == 0, 0.0, raw + 0.5) / 256.0 - 0.5) * 8.0
            rest = values.reshape(n, 3, coeffs).transpose(0, 2, 1)
        return gaussians(
            means,
            log_scales,
            _unpack_rotation(vertex["packed_rotation"]),
            logit(_unorm(colour, 0, 8)),
            sh_from_bands(colour_to_dc(rgb), rest),
        )

    def close(self) -> None:
        self._file.close()


def _checked_chunks(path: Path, chunk: np.ndarray) -> np.ndarray:
    """The chunk table, refused unless every bound is present, finite and min <= max."""
    names = set(chunk.dtype.names or ())
    missing = [b for b in CHUNK_BOUNDS if b not in names]
    if missing:
        raise InputError(f"chunk element lacks {', '.join(missing)}", source=str(path))
    bounds = [b for b in CHUNK_BOUNDS + COLOUR_BOUNDS if b in names]
    for name in bounds:
        bad = int((~np.isfinite(chunk[name])).sum())
        if bad:
            raise InputError(f"chunk bound {name} has {bad} non-finite values", source=str(path))
    for name in bounds:
        if name.startswith("min_"):
            upper = "max_" + name[4:]
            if upper in names:
                inverted = int((chunk[name] > chunk[upper]).sum())
                if inverted:
                    raise InputError(
                        f"chunk bounds {name} > {upper} in {inverted} chunks (a bound's min must not exceed its max)",
                        source=str(path),
                    )
    return chunk


def open_compressed_ply(
    path: Path, max_gaussians: int, *, spill_dir: Path | None = None
) -> CompressedPlySource:
    """Open a compressed PLY for reading by range (`spill_dir` unused: nothing is inflated)."""
    return CompressedPlySource(path, max_gaussians)


def read_compressed_ply(path: Path, max_gaussians: int) -> Gaussians:
    """Decode a compressed PLY into the INRIA parameterisation (see the module docstring)."""
    with open_compressed_ply(path, max_gaussians) as source:
        return source.rows(0, source.count)
