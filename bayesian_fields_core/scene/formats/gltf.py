"""glTF / GLB with the `KHR_gaussian_splatting` extension, read with numpy.

The extension stores a point primitive whose attributes are POSITION (float VEC3),
`KHR_gaussian_splatting:ROTATION` (float VEC4, x y z w), `:SCALE` (float VEC3, linear),
`:OPACITY` (float SCALAR, linear), `:SH_DEGREE_<l>_COEF_<m>` (float VEC3 SH coefficients) and
COLOR_0 (a display colour, ignored when SH_DEGREE_0 is present). glTF is y-up; `splat-transform`
turns a 3DGS PLY 180 degrees about z on the way in (checked on its output: x and y change sign,
z does not), so we turn it back. Only `.glb` (one binary chunk) and `.gltf` with its buffer
embedded as a data URI or a file beside it are read; accessors must be tightly packed.
The JSON is validated as `gltf_doc.GltfDocument` first; then every accessor read is checked
against its view and buffer (count, type, offsets, lengths) before one array is allocated, and
the Gaussians are read by row range from the file (`SplatSource`).
"""

from __future__ import annotations

import base64
import binascii
import io
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO
from urllib.parse import unquote

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
from bayesian_fields_core.scene.formats.gltf_doc import GltfDocument
from bayesian_fields_core.scene.formats.source import SplatSource, read_exact
from bayesian_fields_core.scene.formats.typed_json import MAX_JSON_BYTES, parse_json, typed
from bayesian_fields_core.scene.types import Gaussians

EXTENSION = "KHR_gaussian_splatting"
GLTF_TO_PLY = np.diag([-1.0, -1.0, 1.0])
_COMPONENTS = {"SCALAR": 1, "VEC3": 3, "VEC4": 4}
_TYPES: dict[int, np.dtype] = {5126: np.dtype("<f4"), 5121: np.dtype("u1"), 5123: np.dtype("<u2")}
JSON_CHUNK, BIN_CHUNK = 0x4E4F534A, 0x004E4942


@dataclass(frozen=True)
class _Region:
    """Bytes `offset` .. `offset + length` of an open file (or of decoded data-URI bytes)."""

    file: BinaryIO
    offset: int
    length: int


@dataclass(frozen=True)
class _Column:
    """One accessor, checked: where its rows start, their dtype and width."""

    region: _Region
    start: int
    dtype: np.dtype
    width: int
    normalized: bool


def _split_glb(f: BinaryIO, path: Path) -> tuple[bytes, _Region | None]:
    """(JSON chunk bytes, the binary chunk's region or None), every length checked first."""
    size = path.stat().st_size
    head = f.read(20)
    if len(head) < 20 or head[:4] != b"glTF":
        raise InputError("not a GLB file (bad magic)", source=str(path))
    json_len, json_type = struct.unpack_from("<II", head, 12)
    if json_type != JSON_CHUNK or 20 + json_len > size:
        raise InputError("GLB has no JSON chunk (or its length runs past the file)", source=str(path))
    if json_len > MAX_JSON_BYTES:
        raise InputError(f"GLB JSON chunk is larger than {MAX_JSON_BYTES >> 20} MiB", source=str(path))
    text = f.read(json_len)
    offset = 20 + json_len
    if offset + 8 > size:
        return text, None
    bin_len, bin_type = struct.unpack_from("<II", read_exact(f, offset, 8, what="GLB chunk", source=path))
    if bin_type != BIN_CHUNK:
        return text, None
    if offset + 8 + bin_len > size:
        raise InputError(f"GLB binary chunk of {bin_len} bytes runs past the file", source=str(path))
    return text, _Region(f, offset + 8, bin_len)


class GltfSource(SplatSource):
    """The splat primitive's accessors, read by row range from their regions."""

    def __init__(self, path: Path, n: int, columns: dict[str, _Column], files: list[BinaryIO]) -> None:
        bands = sum(1 for name in columns if name.startswith("sh_"))
        super().__init__(path, n, {0: 0, 3: 1, 8: 2, 15: 3}[bands])
        self.columns, self.files = columns, files

    def _values(self, name: str, start: int, stop: int) -> np.ndarray:
        col = self.columns[name]
        row = col.width * col.dtype.itemsize
        f = col.region.file
        f.seek(col.region.offset + col.start + start * row)
        raw = f.read((stop - start) * row)
        values = np.frombuffer(raw, col.dtype).reshape(stop - start, col.width).astype(np.float32)
        if col.normalized and col.dtype.kind == "u":
            values /= float(np.iinfo(col.dtype).max)
        return values

    def rows(self, start: int, stop: int) -> Gaussians:
        def get(name: str) -> np.ndarray:
            return self._values(name, start, stop)

        if "dc" in self.columns:
            dc = get("dc")
        else:
            dc = colour_to_dc(get("colour")[:, :3])
        bands = [get(name) for name in self.columns if name.startswith("sh_")]
        rest = np.stack(bands, axis=1) if bands else None
        with np.errstate(divide="ignore"):
            log_scales = np.log(get("scale"))
        xyzw = get("rotation")
        g = gaussians(
            get("position"), log_scales, xyzw[:, [3, 0, 1, 2]], logit(get("opacity")[:, 0]),
            sh_from_bands(dc, rest),
        )  # fmt: skip
        return rotate_axes(g, GLTF_TO_PLY)

    def close(self) -> None:
        for f in self.files:
            f.close()


class _Opener:
    """Resolves accessors to checked columns, opening each buffer's region once."""

    def __init__(self, path: Path, doc: GltfDocument, glb_bin: _Region | None, files: list[BinaryIO]) -> None:
        self.path, self.doc, self.glb_bin, self.files = path, doc, glb_bin, files
        self.regions: dict[int, _Region] = {}

    def fail(self, message: str) -> InputError:
        return InputError(message, source=str(self.path))

    def buffer(self, index: int) -> _Region:
        if index in self.regions:
            return self.regions[index]
        if index >= len(self.doc.buffers):
            raise self.fail(f"glTF buffers[{index}] does not exist ({len(self.doc.buffers)} buffers)")
        uri = self.doc.buffers[index].uri
        if uri is None:
            if self.glb_bin is None:
                raise self.fail(f"glTF buffers[{index}] has no uri and the file has no GLB binary chunk")
            region = self.glb_bin
        elif uri.startswith("data:"):
            header, comma, payload = uri.partition(",")
            if not comma or not header.endswith(";base64"):
                raise self.fail(f"glTF buffers[{index}].uri is a data: URI without ';base64,' and a payload")
            try:
                data = base64.b64decode(payload, validate=True)
            except (binascii.Error, ValueError):
                raise self.fail(f"glTF buffers[{index}].uri: the base64 payload does not decode") from None
            region = _Region(io.BytesIO(data), 0, len(data))
        else:
            name = unquote(uri)
            target = resolve_inside(
                self.path.parent, name, what=f"glTF buffers[{index}].uri", source=str(self.path)
            )
            region = self._file_beside(index, name, target)
        self.regions[index] = region
        return region

    def _file_beside(self, index: int, name: str, target: Path) -> _Region:
        """The buffer file `target`, opened. Why the OSError: a name the filesystem refuses
        (a component over 255 bytes: ENAMETOOLONG) fails in `is_file` itself, not as "no file"."""
        try:
            if not target.is_file():
                raise self.fail(
                    f"glTF buffers[{index}].uri names {name[:80]!r}, which is not a file beside it"
                )
            f = open(target, "rb")  # noqa: SIM115 - kept open for the rows; closed by GltfSource
        except OSError as exc:
            raise self.fail(
                f"glTF buffers[{index}].uri names {name[:80]!r}, which cannot be opened ({exc.strerror or exc})"
            ) from None
        self.files.append(f)
        return _Region(f, 0, target.stat().st_size)

    def column(self, attribute: str, index: int, n: int | None, types: tuple[str, ...]) -> _Column:
        """Accessor `index` for `attribute`, checked against its view and buffer (no reads)."""
        doc = self.doc
        if index >= len(doc.accessors):
            raise self.fail(
                f"{attribute} names accessors[{index}], which does not exist ({len(doc.accessors)})"
            )
        acc = doc.accessors[index]
        where = f"accessors[{index}] ({attribute})"
        if n is not None and acc.count != n:
            raise self.fail(f"{where} has {acc.count} items, POSITION has {n}")
        if acc.componentType not in _TYPES or acc.type not in types:
            raise self.fail(
                f"{where} is {acc.type} of componentType {acc.componentType}; expected {' or '.join(types)} "
                "of float (5126), or normalized unsigned byte / short"
            )
        if acc.bufferView >= len(doc.bufferViews):
            raise self.fail(f"{where} names bufferViews[{acc.bufferView}], which does not exist")
        view = doc.bufferViews[acc.bufferView]
        dtype, width = _TYPES[acc.componentType], _COMPONENTS[acc.type]
        if view.byteStride not in (None, dtype.itemsize * width):
            raise self.fail(f"{where} is interleaved (byteStride {view.byteStride}); not supported")
        need = acc.count * width * dtype.itemsize
        if acc.byteOffset + need > view.byteLength:
            raise self.fail(
                f"{where} needs {need} bytes from offset {acc.byteOffset}; its view has {view.byteLength}"
            )
        region = self.buffer(view.buffer)
        if view.byteOffset + view.byteLength > region.length:
            raise self.fail(
                f"bufferViews[{acc.bufferView}] ends at byte {view.byteOffset + view.byteLength}; "
                f"its buffer holds {region.length}"
            )
        return _Column(region, view.byteOffset + acc.byteOffset, dtype, width, acc.normalized)


def open_gltf(path: Path, max_gaussians: int, *, spill_dir: Path | None = None) -> GltfSource:
    """Validate a .glb / .gltf and its splat primitive's accessors; the rows are read later."""
    del spill_dir  # the accessors are read from the file itself
    files: list[BinaryIO] = [open(path, "rb")]  # noqa: SIM115 - closed by GltfSource / below
    try:
        return _open(path, max_gaussians, files)
    except BaseException:
        for f in files:
            f.close()
        raise


def _open(path: Path, max_gaussians: int, files: list[BinaryIO]) -> GltfSource:
    glb_bin = None
    if path.suffix.lower() == ".glb":
        text, glb_bin = _split_glb(files[0], path)
    else:
        text = files[0].read(MAX_JSON_BYTES + 1)
    doc = typed(GltfDocument, parse_json(text, source=path, what="glTF JSON"), source=path, what="glTF JSON")
    prims = [p for mesh in doc.meshes for p in mesh.primitives if EXTENSION in (p.extensions or {})]
    if not prims:
        raise InputError(
            f"no primitive with the {EXTENSION} extension (a mesh, not a splat?)", source=str(path)
        )
    attrs = prims[0].attributes
    key = f"{EXTENSION}:"
    needed = {
        "position": "POSITION",
        "rotation": key + "ROTATION",
        "scale": key + "SCALE",
        "opacity": key + "OPACITY",
    }
    missing = [a for a in needed.values() if a not in attrs]
    if missing:
        raise InputError(f"splat primitive lacks {', '.join(missing)}", source=str(path))
    opener = _Opener(path, doc, glb_bin, files)
    position = opener.column("POSITION", attrs["POSITION"], None, ("VEC3",))
    n = doc.accessors[attrs["POSITION"]].count
    require_count(n, max_gaussians, source=path)
    shapes = {"position": ("VEC3",), "rotation": ("VEC4",), "scale": ("VEC3",), "opacity": ("SCALAR",)}
    columns = {"position": position}
    for name in ("rotation", "scale", "opacity"):
        columns[name] = opener.column(needed[name], attrs[needed[name]], n, shapes[name])
    if key + "SH_DEGREE_0_COEF_0" in attrs:
        columns["dc"] = opener.column("SH_DEGREE_0_COEF_0", attrs[key + "SH_DEGREE_0_COEF_0"], n, ("VEC3",))
    elif "COLOR_0" in attrs:
        columns["colour"] = opener.column("COLOR_0", attrs["COLOR_0"], n, ("VEC3", "VEC4"))
    else:
        raise InputError("splat primitive has neither SH_DEGREE_0_COEF_0 nor COLOR_0", source=str(path))
    for degree in (1, 2, 3):
        names = [f"{key}SH_DEGREE_{degree}_COEF_{m}" for m in range(2 * degree + 1)]
        if not all(name in attrs for name in names):
            break
        for m, name in enumerate(names):
            columns[f"sh_{degree}_{m}"] = opener.column(name, attrs[name], n, ("VEC3",))
    return GltfSource(path, n, columns, files)


def read_gltf(path: Path, max_gaussians: int) -> Gaussians:
    """Decode the first KHR_gaussian_splatting primitive of a .glb / .gltf into the PLY frame."""
    with open_gltf(path, max_gaussians) as source:
        return source.rows(0, source.count)
