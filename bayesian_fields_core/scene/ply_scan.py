"""Check a whole splat file in bounded memory: the upload validator's way of reading a splat.

Why: `read_ply` loads every row and then builds float32 columns and the SH array beside them, so
a 656 MB upload (2 M Gaussians, SH 3, 20 extra properties) took the API to 1.7 GiB, 2.7 times the
file; a few concurrent uploads would exhaust an API pod. Validation needs no resident splat: it
reads the binary body in chunks of about `CHUNK_BYTES` into one buffer at a time, and per chunk
counts what `read_ply` would refuse (non-finite values, `scene.sanity`'s degenerate Gaussians),
tracks the statistics of `scene.sanity.splat_warnings` and keeps the rows of a fixed-seed sample
for the geometric alignment check. Counts add up over chunks, so a refusal names the same
properties and numbers as `read_ply`'s. (Plain reads into a fresh buffer rather than a memory
map: mapped pages count towards the process's resident size while they stay cached.)

Differences from the whole-file path, on purpose: the warnings' extent (1st-99th percentile of
the means) is taken on the sample, exact up to `sample_size` Gaussians and an estimate above; the
per-Gaussian checks are exact. ASCII splats (rare, and small in practice) are read whole with
`read_ply`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

import numpy as np

from bayesian_fields_core.errors import InputError, input_boundary
from bayesian_fields_core.scene.ply import (
    DEFAULT_MAX_GAUSSIANS,
    PlyHeader,
    gaussians_from_rows,
    nonfinite_counts,
    raise_nonfinite,
    read_ply,
    read_ply_header,
)
from bayesian_fields_core.scene.sanity import (
    degenerate_counts,
    huge_count,
    raise_degenerate,
    splat_extent,
    splat_warnings,
    warnings_from,
)
from bayesian_fields_core.scene.types import Gaussians

CHUNK_BYTES = 16 * 1024 * 1024
"""Bytes of vertex rows read at a time (the buffer; the float32 columns add about as much)."""


def sample_index(n: int, size: int) -> np.ndarray:
    """Sorted row indices of the fixed-seed sample the alignment check draws (all rows when
    `n` <= `size`), so a check on the sample sees exactly the Gaussians it would pick itself."""
    if n <= size:
        return np.arange(n)
    return np.sort(np.random.default_rng(0).choice(n, size, replace=False))


@dataclass
class SplatScan:
    """What the validator needs of a splat: its size, the sample and the warnings."""

    count: int
    sh_degree: int
    sample: Gaussians
    """The sampled Gaussians (`sample_index` of `count`), in file order."""
    warnings: list[str] = field(default_factory=list)


def scan_ply(path: str | Path, *, sample_size: int, max_gaussians: int = DEFAULT_MAX_GAUSSIANS) -> SplatScan:
    """Validate a splat like `read_ply` (same refusals, same messages) without holding it."""
    path = Path(path)
    header = read_ply_header(path, max_gaussians=max_gaussians)
    if header.format == "ascii":
        gaussians = read_ply(path, max_gaussians=max_gaussians)
        sample = gaussians.subset(sample_index(len(gaussians), sample_size))
        return SplatScan(len(gaussians), gaussians.sh_degree, sample, splat_warnings(gaussians))
    with input_boundary(str(path), what="cannot read PLY"):
        return _scan_binary(header, sample_size)


def _chunks(header: PlyHeader) -> list[tuple[int, int]]:
    rows = max(1, CHUNK_BYTES // header.dtype().itemsize)
    return [(start, min(start + rows, header.count)) for start in range(0, header.count, rows)]


def _read_chunk(f: BinaryIO, header: PlyHeader, start: int, stop: int) -> np.ndarray:
    rows = np.fromfile(f, dtype=header.dtype(), count=stop - start)
    if rows.shape[0] != stop - start:  # the file shrank after the header's size check
        raise InputError(
            f"truncated vertex data: expected {header.count} rows, got {start + rows.shape[0]}",
            source=str(header.path),
        )
    return rows


def _scan_binary(header: PlyHeader, sample_size: int) -> SplatScan:
    index = sample_index(header.count, sample_size)
    nonfinite: dict[str, int] = {}
    degenerate = np.zeros(3, dtype=np.int64)
    max_opacity = 0.0
    parts: list[Gaussians] = []
    with open(header.path, "rb") as f:
        f.seek(header.data_offset)
        for start, stop in _chunks(header):
            chunk, groups = gaussians_from_rows(header, _read_chunk(f, header, start, stop))
            for name, n in nonfinite_counts(groups).items():
                nonfinite[name] = nonfinite.get(name, 0) + n
            degenerate += degenerate_counts(chunk)
            max_opacity = max(max_opacity, float(chunk.opacities.max()))  # NaN: refused below
            lo, hi = np.searchsorted(index, [start, stop])
            parts.append(chunk.subset(index[lo:hi] - start))
            del chunk, groups
    raise_nonfinite(header.path, nonfinite)
    raise_degenerate((int(degenerate[0]), int(degenerate[1]), int(degenerate[2])), source=str(header.path))
    sample = concat_gaussians(parts)
    extent = splat_extent(sample.means)
    huge = _huge_count(header, extent) if extent > 0.0 else 0
    return SplatScan(
        header.count, header.sh_degree, sample, warnings_from(header.count, max_opacity, extent, huge)
    )


def _huge_count(header: PlyHeader, extent: float) -> int:
    """Second pass, scales only: how many Gaussians are wider than the sample's extent."""
    names = ["scale_0", "scale_1", "scale_2"]
    total = 0
    with open(header.path, "rb") as f:
        f.seek(header.data_offset)
        for start, stop in _chunks(header):
            rows = _read_chunk(f, header, start, stop)
            scales = np.stack([rows[n].astype(np.float32) for n in names], axis=1)
            total += huge_count(scales, extent)
    return total


def concat_gaussians(parts: list[Gaussians]) -> Gaussians:
    """The parts, in order, as one `Gaussians` (extra properties of the first part's keys)."""
    return Gaussians(
        means=np.concatenate([p.means for p in parts]),
        log_scales=np.concatenate([p.log_scales for p in parts]),
        quats=np.concatenate([p.quats for p in parts]),
        opacity_logits=np.concatenate([p.opacity_logits for p in parts]),
        sh=np.concatenate([p.sh for p in parts]),
        extra={k: np.concatenate([p.extra[k] for p in parts]) for k in parts[0].extra},
    )
