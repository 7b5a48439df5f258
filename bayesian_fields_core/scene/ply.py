"""Read and write 3D Gaussian Splat `.ply` files in the INRIA layout.

Layout (per vertex): x, y, z, nx, ny, nz, f_dc_0..2, f_rest_0..(3*(K-1)-1), opacity,
scale_0..2 (log std), rot_0..3 (w, x, y, z). `f_rest` is channel-major: property index
`c * (K - 1) + j` holds SH coefficient `j + 1` of colour channel `c`.

We parse the header ourselves and read the binary body with one structured-dtype `np.fromfile`
instead of going through plyfile: it gives precise error messages (which property is missing,
how many bytes are short) *before* touching the body, and a 1M-Gaussian file loads in a fraction of
a second. The cheap `read_ply_header` runs the same checks without reading the body, so the API can
reject a bad upload immediately.
"""

from __future__ import annotations

import io
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.lib import recfunctions

from bayesian_fields_core.errors import InputError, describe_failure, input_boundary
from bayesian_fields_core.scene.point_cloud import is_point_cloud, point_cloud_message
from bayesian_fields_core.scene.sanity import check_splat
from bayesian_fields_core.scene.types import Gaussians, sh_coefficient_count

DEFAULT_MAX_GAUSSIANS = 20_000_000
"""Largest vertex count accepted by default; guards memory against absurd or hostile headers."""

MAX_HEADER_BYTES = 1 << 20
"""A PLY header longer than this is treated as corrupt (real splat headers are ~2 KiB)."""

# PLY scalar type names (both spellings) -> numpy type characters (byte order added later).
_PLY_TYPES: dict[str, str] = {
    "char": "i1",
    "int8": "i1",
    "uchar": "u1",
    "uint8": "u1",
    "short": "i2",
    "int16": "i2",
    "ushort": "u2",
    "uint16": "u2",
    "int": "i4",
    "int32": "i4",
    "uint": "u4",
    "uint32": "u4",
    "float": "f4",
    "float32": "f4",
    "double": "f8",
    "float64": "f8",
}
_NUMPY_TO_PLY: dict[str, str] = {
    "i1": "char",
    "u1": "uchar",
    "i2": "short",
    "u2": "ushort",
    "i4": "int",
    "u4": "uint",
    "f4": "float",
    "f8": "double",
}
_FORMATS = {"ascii": None, "binary_little_endian": "<", "binary_big_endian": ">"}
_SH_DEGREE_BY_REST = {3 * (sh_coefficient_count(d) - 1): d for d in range(4)}  # {0:0, 9:1, 24:2, 45:3}

MEANS = ("x", "y", "z")
NORMALS = ("nx", "ny", "nz")
F_DC = ("f_dc_0", "f_dc_1", "f_dc_2")
OPACITY = ("opacity",)
SCALES = ("scale_0", "scale_1", "scale_2")
ROTATIONS = ("rot_0", "rot_1", "rot_2", "rot_3")
REQUIRED = MEANS + F_DC + OPACITY + SCALES + ROTATIONS
_F_REST = re.compile(r"f_rest_(\d+)$")


@dataclass
class PlyHeader:
    """What the header of a splat file declares; `data_offset` is where the vertex rows start.

    For ASCII files `data_offset` is the end of the header and `skip_lines` the number of rows of
    elements that precede `vertex`.
    """

    path: Path
    format: str
    count: int
    properties: list[tuple[str, str]]  # (name, numpy type char without byte order), file order
    sh_degree: int
    data_offset: int
    skip_lines: int = 0
    file_size: int = 0
    trailing_elements: int = 0  # elements declared after `vertex` (their rows follow the vertices)
    comments: list[str] = field(default_factory=list)

    @property
    def byte_order(self) -> str | None:
        return _FORMATS[self.format]

    def dtype(self) -> np.dtype:
        """Structured dtype of one binary vertex row (native order for ASCII)."""
        order = self.byte_order or "="
        return np.dtype([(name, order + t) for name, t in self.properties])


def _fail(path: Path, message: str) -> InputError:
    return InputError(message, source=str(path))


def _read_header_bytes(path: Path) -> tuple[str, int]:
    """The header text and its length in bytes (end_header line included)."""
    try:
        with open(path, "rb") as f:
            head = f.read(MAX_HEADER_BYTES)
    except OSError as exc:
        raise _fail(path, f"cannot read file ({exc.strerror})") from exc
    if not (head.startswith(b"ply\n") or head.startswith(b"ply\r\n")):
        raise _fail(path, "not a PLY file (it does not start with the 'ply' magic line)")
    match = re.search(rb"(?:^|\n)end_header[ \t]*\r?\n", head)
    if match is None:
        if len(head) >= MAX_HEADER_BYTES:
            raise _fail(path, f"PLY header longer than {MAX_HEADER_BYTES} bytes or missing end_header")
        raise _fail(path, "PLY header has no end_header line (file truncated?)")
    try:
        text = head[: match.end()].decode("ascii")
    except UnicodeDecodeError as exc:
        raise _fail(path, "PLY header contains non-ASCII bytes") from exc
    return text, match.end()


def _parse_elements(path: Path, text: str) -> tuple[str, list[tuple[str, int, list]], list[str]]:
    """Format name, elements [(name, count, [(prop, type) | (prop, 'list', ...)])], comments."""
    fmt: str | None = None
    elements: list[tuple[str, int, list]] = []
    comments: list[str] = []
    for lineno, raw in enumerate(text.splitlines()[1:], start=2):
        tokens = raw.split()
        if not tokens or tokens[0] in ("end_header", "obj_info"):
            continue
        key = tokens[0]
        if key == "comment":
            comments.append(raw.strip()[len("comment") :].strip())
        elif key == "format":
            if len(tokens) != 3 or tokens[1] not in _FORMATS:
                raise _fail(path, f"header line {lineno}: unsupported format line {raw.strip()!r}")
            fmt = tokens[1]
        elif key == "element":
            if len(tokens) != 3 or not re.fullmatch(r"\d+", tokens[2]):
                raise _fail(path, f"header line {lineno}: malformed element line {raw.strip()!r}")
            elements.append((tokens[1], int(tokens[2]), []))
        elif key == "property":
            if not elements:
                raise _fail(path, f"header line {lineno}: property before any element")
            props = elements[-1][2]
            if len(tokens) == 5 and tokens[1] == "list":
                props.append((tokens[4], "list", tokens[2], tokens[3]))
            elif len(tokens) == 3 and tokens[1] in _PLY_TYPES:
                props.append((tokens[2], _PLY_TYPES[tokens[1]]))
            else:
                raise _fail(path, f"header line {lineno}: malformed property line {raw.strip()!r}")
        else:
            raise _fail(path, f"header line {lineno}: unknown keyword {key!r}")
    if fmt is None:
        raise _fail(path, "PLY header has no format line")
    return fmt, elements, comments


def read_ply_elements(path: str | Path) -> tuple[str, list[tuple[str, int, list]], int]:
    """(format, elements [(name, count, properties)], header length) of any PLY, unchecked
    against the INRIA layout: the splat-format dispatcher and the compressed-PLY reader start here."""
    path = Path(path)
    text, header_len = _read_header_bytes(path)
    fmt, elements, _ = _parse_elements(path, text)
    return fmt, elements, header_len


def _sh_degree(path: Path, names: list[str]) -> int:
    rest = sorted(int(m.group(1)) for n in names if (m := _F_REST.match(n)))
    if len(rest) not in _SH_DEGREE_BY_REST:
        raise _fail(
            path,
            f"{len(rest)} f_rest_* properties; a splat has 0, 9, 24 or 45 (SH degree 0 to 3)",
        )
    if rest != list(range(len(rest))):
        raise _fail(path, f"f_rest_* properties are not numbered 0..{len(rest) - 1}")
    return _SH_DEGREE_BY_REST[len(rest)]


def read_ply_header(path: str | Path, *, max_gaussians: int = DEFAULT_MAX_GAUSSIANS) -> PlyHeader:
    """Validate a splat file's header against the INRIA layout and the file size, cheaply.

    Checks: PLY magic, a `vertex` element of scalar properties, every required property present
    and float-typed, an f_rest count meaning SH degree 0..3, the vertex count within
    `max_gaussians` and above 0, and (binary) the file as long as the declared rows (shorter:
    truncated; a row or more longer: the count does not match the body). Reads only the header.
    """
    with input_boundary(str(path), what="cannot read PLY header"):
        return _read_ply_header(Path(path), max_gaussians)


def _read_ply_header(path: Path, max_gaussians: int) -> PlyHeader:
    text, header_len = _read_header_bytes(path)
    fmt, elements, comments = _parse_elements(path, text)
    file_size = os.path.getsize(path)

    names = [e[0] for e in elements]
    if "vertex" not in names:
        raise _fail(path, f"no 'vertex' element (elements: {', '.join(names) or 'none'})")
    vindex = names.index("vertex")
    _, count, vprops = elements[vindex]
    lists = [p[0] for p in vprops if p[1] == "list"]
    if lists:
        raise _fail(path, f"vertex element has list properties ({', '.join(lists)}); a splat has none")
    props: list[tuple[str, str]] = [(p[0], p[1]) for p in vprops]
    prop_names = [p[0] for p in props]
    dupes = sorted({n for n in prop_names if prop_names.count(n) > 1})
    if dupes:
        raise _fail(path, f"duplicate vertex properties: {', '.join(dupes)}")
    missing = [n for n in REQUIRED if n not in prop_names]
    if missing and is_point_cloud(set(prop_names)):
        raise _fail(path, point_cloud_message(set(prop_names)))
    if missing:
        raise _fail(
            path,
            f"missing required vertex properties: {', '.join(missing)} (not a Gaussian splat in the "
            "INRIA, compressed or RGB layout; if splat-transform reads it, convert it: "
            f"npx @playcanvas/splat-transform {path.name} splat.ply)",
        )
    types = dict(props)
    sh_degree = _sh_degree(path, prop_names)
    not_float = [
        f"{n} ({_NUMPY_TO_PLY[types[n]]})" for n in prop_names if _needs_float(n) and types[n][0] != "f"
    ]
    if not_float:
        raise _fail(path, f"required properties must be float or double: {', '.join(not_float)}")
    if count > max_gaussians:
        raise _fail(path, f"vertex count {count} exceeds the limit max_gaussians={max_gaussians}")
    if count == 0:
        raise _fail(path, "the splat has no Gaussians (element vertex 0)")

    header = PlyHeader(path, fmt, count, props, sh_degree, header_len, file_size=file_size, comments=comments)
    header.trailing_elements = len(elements) - vindex - 1
    if fmt == "ascii":
        header.skip_lines = sum(e[1] for e in elements[:vindex])
        # Every value takes at least one character plus a separator (or the newline).
        min_bytes = count * 2 * len(props)
        if file_size - header_len < min_bytes:
            raise _fail(
                path,
                f"vertex count {count} is inconsistent with the file size: {count} ASCII rows need "
                f"at least {min_bytes} bytes, the body has {file_size - header_len}",
            )
        return header

    order = _FORMATS[fmt]
    for ename, ecount, eprops in elements[:vindex]:
        if any(p[1] == "list" for p in eprops):
            raise _fail(path, f"element {ename!r} before 'vertex' has list properties; cannot skip it")
        header.data_offset += ecount * np.dtype([(p[0], order + p[1]) for p in eprops]).itemsize
    stride = header.dtype().itemsize
    needed = count * stride
    available = file_size - header.data_offset
    if available < needed:
        raise _fail(
            path,
            f"truncated vertex data: expected {count} x {stride} = {needed} bytes, got {max(available, 0)}",
        )
    after = elements[vindex + 1 :]
    if not any(p[1] == "list" for _, _, eprops in after for p in eprops):
        declared = needed + sum(
            c * np.dtype([(p[0], order + p[1]) for p in ps]).itemsize for _, c, ps in after
        )
        # A few stray bytes (a trailing newline some writers add) are tolerated; a whole row or
        # more means the vertex count is smaller than the data.
        if available - declared >= stride:
            raise _fail(
                path,
                f"the body is {available - declared} bytes longer than the header declares "
                f"({count} vertices x {stride} bytes); the vertex count does not match the data",
            )
    return header


def _needs_float(name: str) -> bool:
    return name in REQUIRED or _F_REST.match(name) is not None


def _read_rows(header: PlyHeader) -> np.ndarray:
    """The vertex rows as a structured array in the file's dtype."""
    path = header.path
    if header.format != "ascii":
        with open(path, "rb") as f:
            f.seek(header.data_offset)
            rows = np.fromfile(f, dtype=header.dtype(), count=header.count)
        if rows.shape[0] != header.count:  # the file shrank between the size check and the read
            raise _fail(path, f"truncated vertex data: expected {header.count} rows, got {rows.shape[0]}")
        return rows
    with open(path, "rb") as raw:
        raw.seek(header.data_offset)
        text = io.TextIOWrapper(raw, encoding="ascii", errors="strict")
        try:
            # Without trailing elements every remaining row must be a vertex, so a body longer
            # than the header's count is caught (max_rows=None reads to the end).
            values = np.loadtxt(
                text,
                dtype=np.float64,
                skiprows=header.skip_lines,
                max_rows=header.count if header.trailing_elements else None,
                ndmin=2,
                comments=None,
            )
        except (ValueError, UnicodeDecodeError) as exc:
            raise _fail(path, f"malformed ASCII vertex data ({describe_failure(exc)})") from exc
    if values.shape[0] > header.count:
        raise _fail(
            path,
            f"the body has {values.shape[0]} rows but the header declares {header.count} vertices; "
            "the vertex count does not match the data",
        )
    if values.shape[0] != header.count or (header.count and values.shape[1] != len(header.properties)):
        raise _fail(
            path,
            f"truncated or malformed ASCII vertex data: expected {header.count} rows of "
            f"{len(header.properties)} values, got {values.shape[0]} rows of {values.shape[1]}",
        )
    return recfunctions.unstructured_to_structured(values, dtype=header.dtype())


def _columns(rows: np.ndarray, names: tuple[str, ...] | list[str]) -> np.ndarray:
    """The named fields as one (N, len(names)) native float32 array."""
    return np.ascontiguousarray(recfunctions.structured_to_unstructured(rows[list(names)], dtype=np.float32))


def nonfinite_counts(groups: dict[tuple[str, ...], np.ndarray]) -> dict[str, int]:
    """Non-finite values per property name (counts add up over chunks of rows)."""
    counts: dict[str, int] = {}
    for names, values in groups.items():
        bad = (~np.isfinite(values)).reshape(values.shape[0], -1).sum(axis=0)
        for name, n in zip(names, bad, strict=True):
            counts[name] = counts.get(name, 0) + int(n)
    return counts


def raise_nonfinite(path: Path, counts: dict[str, int]) -> None:
    """InputError naming every property with non-finite values (nothing when there are none)."""
    problems = [f"{n} in {name}" for name, n in counts.items() if n]
    if problems:
        total = sum(counts.values())
        raise _fail(path, f"{total} non-finite values (NaN or inf): {', '.join(problems)}")


def _check_finite(path: Path, groups: dict[tuple[str, ...], np.ndarray]) -> None:
    raise_nonfinite(path, nonfinite_counts(groups))


def read_ply(path: str | Path, *, max_gaussians: int = DEFAULT_MAX_GAUSSIANS) -> Gaussians:
    """Load a splat; properties outside the INRIA set (normals included) land in `extra`.

    Refuses, as InputError: anything `read_ply_header` refuses, non-finite values, the degenerate
    splats of `scene.sanity.check_splat`, and any other failure to parse the file.
    """
    with input_boundary(str(path), what="cannot read PLY"):
        gaussians = _read_ply(Path(path), max_gaussians)
    check_splat(gaussians, source=str(path))
    return gaussians


def _read_ply(path: Path, max_gaussians: int) -> Gaussians:
    header = read_ply_header(path, max_gaussians=max_gaussians)
    gaussians, groups = gaussians_from_rows(header, _read_rows(header))
    _check_finite(header.path, groups)
    return gaussians


def gaussians_from_rows(
    header: PlyHeader, rows: np.ndarray
) -> tuple[Gaussians, dict[tuple[str, ...], np.ndarray]]:
    """Gaussians from structured vertex rows (all of a file's, or one chunk of them), and the
    column groups whose values must be finite (unchecked here)."""
    n = rows.shape[0]
    k = sh_coefficient_count(header.sh_degree)
    rest_names = tuple(f"f_rest_{i}" for i in range(3 * (k - 1)))

    means = _columns(rows, MEANS)
    f_dc = _columns(rows, F_DC)
    rest = _columns(rows, rest_names) if rest_names else np.zeros((n, 0), np.float32)
    opacity = _columns(rows, OPACITY)
    scales = _columns(rows, SCALES)
    quats = _columns(rows, ROTATIONS)
    groups = {MEANS: means, F_DC: f_dc, rest_names: rest, OPACITY: opacity, SCALES: scales, ROTATIONS: quats}

    sh = np.empty((n, k, 3), dtype=np.float32)
    sh[:, 0, :] = f_dc
    sh[:, 1:, :] = rest.reshape(n, 3, k - 1).transpose(0, 2, 1)
    known = set(REQUIRED) | set(rest_names)
    extra = {
        name: rows[name].astype(np.dtype(t).newbyteorder("="))
        for name, t in header.properties
        if name not in known
    }
    gaussians = Gaussians(
        means=means,
        log_scales=scales,
        quats=quats,
        opacity_logits=opacity[:, 0].copy(),
        sh=sh,
        extra=extra,
    )
    return gaussians, groups


def _output_layout(g: Gaussians) -> list[tuple[str, np.dtype, np.ndarray]]:
    """(name, little-endian dtype, (N,) values) for every property, in INRIA order."""
    n = len(g)
    k = g.sh.shape[1] if g.sh.ndim == 3 else -1
    if g.sh.ndim != 3 or g.sh.shape[0] != n or g.sh.shape[2] != 3 or k not in (1, 4, 9, 16):
        raise InputError(f"Gaussians.sh must have shape (N, 1|4|9|16, 3), got {g.sh.shape}")
    expected = {"means": (n, 3), "log_scales": (n, 3), "quats": (n, 4), "opacity_logits": (n,)}
    for attr, shape in expected.items():
        if getattr(g, attr).shape != shape:
            raise InputError(f"Gaussians.{attr} must have shape {shape}, got {getattr(g, attr).shape}")
    for name, values in g.extra.items():
        if values.shape != (n,) or values.dtype.str[1:] not in _NUMPY_TO_PLY:
            raise InputError(
                f"Gaussians.extra[{name!r}] must be an (N,) numeric array, got {values.dtype}{values.shape}"
            )

    f4 = np.dtype("<f4")
    cols: list[tuple[str, np.dtype, np.ndarray]] = [(nm, f4, g.means[:, i]) for i, nm in enumerate(MEANS)]
    # Always write normals (zeros when absent) like the INRIA code, since some viewers read a fixed layout.
    cols += [
        (nm, g.extra[nm].dtype.newbyteorder("<") if nm in g.extra else f4, g.extra.get(nm, np.zeros(n, f4)))
        for nm in NORMALS
    ]
    cols += [(nm, f4, g.sh[:, 0, c]) for c, nm in enumerate(F_DC)]
    cols += [(f"f_rest_{c * (k - 1) + j}", f4, g.sh[:, 1 + j, c]) for c in range(3) for j in range(k - 1)]
    cols.append(("opacity", f4, g.opacity_logits))
    cols += [(nm, f4, g.log_scales[:, i]) for i, nm in enumerate(SCALES)]
    cols += [(nm, f4, g.quats[:, i]) for i, nm in enumerate(ROTATIONS)]
    taken = {c[0] for c in cols}
    cols += [(nm, v.dtype.newbyteorder("<"), v) for nm, v in g.extra.items() if nm not in taken]
    return cols


def ply_rows(gaussians: Gaussians, *, ascii: bool = False) -> tuple[bytes, np.ndarray]:
    """(header, (N,) structured little-endian rows) of a splat in the INRIA layout: the binary
    file is the header followed by the rows' bytes. Writers of several files of one layout (the
    per-task exports) fill one row array and change only the columns that differ."""
    cols = _output_layout(gaussians)
    fmt = "ascii" if ascii else "binary_little_endian"
    lines = ["ply", f"format {fmt} 1.0", f"element vertex {len(gaussians)}"]
    lines += [f"property {_NUMPY_TO_PLY[dt.str[1:]]} {name}" for name, dt, _ in cols]
    lines.append("end_header\n")
    rows = np.empty(len(gaussians), dtype=np.dtype([(name, dt) for name, dt, _ in cols]))
    for name, _, values in cols:
        rows[name] = values
    return "\n".join(lines).encode("ascii"), rows


def write_ply(path: str | Path, gaussians: Gaussians, *, ascii: bool = False) -> None:
    """Write a splat in the INRIA layout (binary little-endian, or ASCII for inspection).

    Extra properties are appended after rot_3 with their own dtypes, so a read/write round trip
    keeps every property and value bit for bit.
    """
    header, rows = ply_rows(gaussians, ascii=ascii)
    with open(Path(path), "wb") as f:
        f.write(header)
        if not ascii:
            rows.tofile(f)
            return
        # %.9g round-trips float32 exactly and %.17g float64; integers stay integers.
        fmts = {"f4": "%.9g", "f8": "%.17g"}
        assert rows.dtype.names is not None  # a structured array
        np.savetxt(
            f,
            rows,
            fmt=[fmts.get(rows.dtype[name].str[1:], "%d") for name in rows.dtype.names],
            delimiter=" ",
        )
