"""Niantic SPZ (`.spz`), versions 1 to 4, read with numpy (zlib for v1-3, zstandard for v4).

Layout facts: v1-3 are one gzip stream holding a 16-byte header (magic "NGSP", version,
count, SH degree, fractional bits, flags, reserved) then the attribute blocks in this order:
positions (v1: float16 x3; v2+: 24-bit signed fixed point x3, divided by 2^fractional_bits),
alphas (uint8, opacity = a / 255), colours (uint8 x3, DC = (c / 255 - 0.5) / 0.15), scales
(uint8 x3, log-scale = s / 16 - 10), rotations (v1-2: uint8 x3 for x, y, z with w >= 0
derived; v3+: 32-bit "smallest three": top 2 bits the index of the largest component in
x, y, z, w order, then per other component from the low bits up 9 bits of magnitude (in
units of 1/sqrt2 / 511) and a sign bit), SH (uint8, (q - 128) / 128, coefficient-major with
the three channels innermost). v4 ("NGSP" uncompressed, 32-byte header with the stream count
and the table-of-contents offset) stores each block as its own zstd stream, listed in the TOC
as (compressed size, uncompressed size) uint64 pairs.

Axes: SPZ stores right-up-back (RUB); a 3DGS PLY is right-down-forward, so the converters turn
the scene 180 degrees about x on the way in. We turn it back (a proper rotation, so quaternions
and SH bands follow), and the result matches the PLY the file was made from. Checked against
`splat-transform`'s own SPZ -> PLY output and against gsply (which returns the stored RUB values).
"""

from __future__ import annotations

import gzip
import io
import struct
import zlib
from pathlib import Path
from typing import BinaryIO

import numpy as np

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.scene.formats.common import gaussians, logit, require_count, rotate_axes
from bayesian_fields_core.scene.formats.source import (
    READ_BYTES,
    ByteStore,
    FileWindow,
    SplatSource,
    file_chunks,
    read_exact,
)
from bayesian_fields_core.scene.types import Gaussians, sh_coefficient_count

MAGIC = 0x5053474E  # "NGSP" little-endian
RUB_TO_PLY = np.diag([1.0, -1.0, -1.0])
COLOUR_SCALE = 0.15
FRACTIONAL_BITS = (1, 23)
"""Fractional bits a position may use: the positions are 24-bit signed fixed point, so 0 would
make every coordinate an integer up to 8.4 M and 24 or more leave no integer bit (Niantic's
writer uses 12). Outside this range the file is refused rather than read as nonsense."""
GZIP_FAILURES = (OSError, EOFError, zlib.error)
"""What `gzip` raises on a corrupt stream: a bad header or CRC (BadGzipFile, an OSError), an
early end (EOFError) and deflate data that does not decode (`zlib.error`, not an OSError)."""
MAX_DEFLATE_RATIO = 1032
"""Deflate's largest possible expansion (one 258-byte match per 2 bits): a gzip stream of `c`
bytes cannot hold more than about `c * MAX_DEFLATE_RATIO` bytes, so a header declaring more
Gaussians than that is refused before anything is inflated."""


def _row_bytes(sh_dim: int, version: int) -> list[tuple[str, int]]:
    """(block name, bytes per Gaussian), in the file's order."""
    return [
        ("positions", 6 if version == 1 else 9),
        ("alphas", 1),
        ("colors", 3),
        ("scales", 3),
        ("rotations", 4 if version >= 3 else 3),
        ("sh", sh_dim * 3),
    ]


def _header(buf: bytes, path: Path, max_gaussians: int) -> tuple[int, int, int, int]:
    if len(buf) < 16:
        raise InputError("SPZ header is truncated", source=str(path))
    magic, version, n, degree, frac = struct.unpack_from("<IIIBB", buf, 0)
    if magic != MAGIC:
        raise InputError("not an SPZ file (bad magic)", source=str(path))
    if version not in (1, 2, 3, 4):
        raise InputError(f"SPZ version {version} is not supported (1 to 4)", source=str(path))
    if degree > 3:
        raise InputError(f"SPZ SH degree {degree} is not supported (0 to 3)", source=str(path))
    lo, hi = FRACTIONAL_BITS
    if version >= 2 and not lo <= frac <= hi:
        raise InputError(
            f"SPZ fractional bits {frac} outside {lo}..{hi} (24-bit fixed-point positions)", source=str(path)
        )
    require_count(n, max_gaussians, source=path)
    return version, n, degree, frac


class SpzSource(SplatSource):
    """An SPZ payload held in a `ByteStore`, decoded by row range (module docstring)."""

    def __init__(self, path: Path, store: ByteStore, n: int, degree: int, version: int, frac: int) -> None:
        super().__init__(path, n, degree)
        self.store, self.version, self.frac = store, version, frac
        self.sh_dim = sh_coefficient_count(degree) - 1

    def rows(self, start: int, stop: int) -> Gaussians:
        m = stop - start
        parts = {
            name: self.store.read(name, start * width, m * width) if width else b""
            for name, width in _row_bytes(self.sh_dim, self.version)
        }
        return rotate_axes(_decode(parts, m, self.sh_dim, self.version, self.frac), RUB_TO_PLY)

    def close(self) -> None:
        self.store.close()


def open_spz(path: Path, max_gaussians: int, *, spill_dir: Path | None = None) -> SpzSource:
    """Check an SPZ header against its payload, then inflate the payload (bounded by what the
    header declares) into a store; `spill_dir` puts the store in a temporary file there."""
    store = ByteStore(spill_dir)
    try:
        with open(path, "rb") as f:
            if f.read(2) == b"\x1f\x8b":
                return _open_gzip(path, f, store, max_gaussians)
            return _open_v4(path, f, store, max_gaussians)
    except BaseException:
        store.close()
        raise


def _open_gzip(path: Path, f: BinaryIO, store: ByteStore, max_gaussians: int) -> SpzSource:
    f.seek(0)
    size = path.stat().st_size
    with gzip.GzipFile(fileobj=f, mode="rb") as stream:
        try:
            head = stream.read(16)
        except GZIP_FAILURES as exc:
            raise InputError(f"corrupt SPZ gzip stream ({exc})", source=str(path)) from None
        version, n, degree, frac = _header(head, path, max_gaussians)
        sh_dim = sh_coefficient_count(degree) - 1
        blocks = _row_bytes(sh_dim, version)
        total = 16 + n * sum(width for _, width in blocks)
        if total > size * MAX_DEFLATE_RATIO:
            raise InputError(
                f"the header declares {n} Gaussians ({total} bytes) but a {size}-byte gzip stream "
                f"holds at most {size * MAX_DEFLATE_RATIO}",
                source=str(path),
            )
        for name, width in blocks:
            if width:
                try:
                    store.write(name, file_chunks(stream, n * width), n * width, source=path)  # type: ignore[arg-type]
                except GZIP_FAILURES as exc:
                    raise InputError(f"corrupt SPZ gzip stream ({exc})", source=str(path)) from None
    return SpzSource(path, store, n, degree, version, frac)


def _open_v4(path: Path, f: BinaryIO, store: ByteStore, max_gaussians: int) -> SpzSource:
    f.seek(0)
    head = f.read(32)
    version, n, degree, frac = _header(head, path, max_gaussians)
    if version < 4:
        raise InputError(f"SPZ v{version} must be gzip-compressed", source=str(path))
    if len(head) < 32:
        raise InputError("SPZ v4 header is truncated", source=str(path))
    try:
        import zstandard
    except ImportError:  # pragma: no cover - a declared dependency
        raise InputError(
            "SPZ v4 needs the zstandard package; or rewrite it as v3: "
            f"npx @playcanvas/splat-transform --spz-version 3 {path.name} out.spz",
            source=str(path),
        ) from None
    sh_dim = sh_coefficient_count(degree) - 1
    size = path.stat().st_size
    streams, toc = struct.unpack_from("<BI", head, 15)
    blocks = [(name, width) for name, width in _row_bytes(sh_dim, 4) if width]
    if streams != len(blocks) or toc < 32 or toc + 16 * streams > size:
        raise InputError(f"SPZ v4 table of contents is inconsistent ({streams} streams)", source=str(path))
    table = read_exact(f, toc, 16 * streams, what="SPZ v4 table of contents", source=path)
    offset = toc + 16 * streams
    for i, (name, width) in enumerate(blocks):
        csize, usize = struct.unpack_from("<QQ", table, 16 * i)
        if usize != n * width or offset + csize > size:
            raise InputError(f"SPZ v4 stream {name!r} has the wrong size", source=str(path))
        window = io.BufferedReader(FileWindow(f, offset, csize), READ_BYTES)
        reader = zstandard.ZstdDecompressor().stream_reader(window, closefd=False)
        try:
            store.write(name, file_chunks(reader, usize), usize, source=path)
        except zstandard.ZstdError as exc:
            raise InputError(f"corrupt SPZ v4 stream {name!r} ({exc})", source=str(path)) from None
        offset += csize
    return SpzSource(path, store, n, degree, version, frac)


def _smallest_three(packed: np.ndarray) -> np.ndarray:
    """(N,) uint32 -> (N, 4) quaternions in x, y, z, w order."""
    largest = (packed >> np.uint32(30)).astype(np.int64)
    q = np.zeros((packed.shape[0], 4), np.float64)
    comp = packed.copy()
    total = np.zeros(packed.shape[0])
    scale = np.sqrt(0.5) / 511.0
    for i in (3, 2, 1, 0):
        rows = largest != i
        mag = (comp & np.uint32(511)).astype(np.float64) * scale
        neg = ((comp >> np.uint32(9)) & np.uint32(1)).astype(bool)
        value = np.where(neg, -mag, mag)
        q[rows, i] = value[rows]
        total[rows] += value[rows] ** 2
        comp = np.where(rows, comp >> np.uint32(10), comp)
    q[np.arange(len(q)), largest] = np.sqrt(np.clip(1.0 - total, 0.0, 1.0))
    return q


def read_spz(path: Path, max_gaussians: int) -> Gaussians:
    """Decode a whole SPZ file into the PLY's frame and parameterisation (module docstring)."""
    with open_spz(path, max_gaussians) as source:
        return source.rows(0, source.count)


def _decode(parts: dict[str, bytes], n: int, sh_dim: int, version: int, frac: int) -> Gaussians:
    u8 = {k: np.frombuffer(v, np.uint8) for k, v in parts.items()}
    means: np.ndarray
    if version == 1:
        means = np.frombuffer(parts["positions"], "<f2").reshape(n, 3).astype(np.float32)
    else:
        p = u8["positions"].reshape(n, 3, 3).astype(np.int32)
        fixed = p[..., 0] | (p[..., 1] << 8) | (p[..., 2] << 16)
        fixed = np.where(fixed & 0x800000, fixed - (1 << 24), fixed)
        means = fixed.astype(np.float64) / float(1 << frac)
    opacity = u8["alphas"].astype(np.float32) / 255.0
    dc = (u8["colors"].reshape(n, 3).astype(np.float32) / 255.0 - 0.5) / COLOUR_SCALE
    log_scales = u8["scales"].reshape(n, 3).astype(np.float32) / 16.0 - 10.0
    if version >= 3:
        xyzw = _smallest_three(np.frombuffer(parts["rotations"], "<u4").astype(np.uint32))
    else:
        xyz = u8["rotations"].reshape(n, 3).astype(np.float64) / 127.5 - 1.0
        w = np.sqrt(np.clip(1.0 - (xyz**2).sum(axis=1), 0.0, 1.0))
        xyzw = np.concatenate([xyz, w[:, None]], axis=1)
    quats = xyzw[:, [3, 0, 1, 2]]
    sh = np.empty((n, sh_dim + 1, 3), np.float32)
    sh[:, 0] = dc
    if sh_dim:
        sh[:, 1:] = (u8["sh"].reshape(n, sh_dim, 3).astype(np.float32) - 128.0) / 128.0
    return gaussians(means, log_scales, quats, logit(opacity), sh)
