"""Check a splat of any non-INRIA format in bounded memory, as `scene.ply_scan` does for PLYs.

Why: the upload check must refuse what `read_splat` would refuse (non-finite values, degenerate
Gaussians) and compute the same warnings and alignment sample, without holding the splat: a
compressed format decodes to several times its size, and its header may declare far more than
its payload. The source (`formats.open_source`, payloads spilled beside the upload) is walked in
chunks of about `CHUNK_BYTES` of decoded floats; counts add up over chunks so messages match
the whole-file path, the fixed-seed sample is kept, and a second pass counts huge Gaussians
against the sample's extent (exact up to `sample_size` Gaussians, an estimate above).
"""

from __future__ import annotations

import numpy as np

from bayesian_fields_core.scene.formats.common import nonfinite_counts, raise_nonfinite
from bayesian_fields_core.scene.formats.source import SplatSource
from bayesian_fields_core.scene.ply_scan import SplatScan, concat_gaussians, sample_index
from bayesian_fields_core.scene.sanity import (
    degenerate_counts,
    huge_count,
    raise_degenerate,
    splat_extent,
    warnings_from,
)
from bayesian_fields_core.scene.types import Gaussians

CHUNK_BYTES = 4 * 1024 * 1024
"""Decoded float32 bytes per chunk. Smaller than the PLY scan's: decoding works in float64 and
turns SPZ's and glTF's axes back (SH bands included), several temporaries per chunk."""
FLOATS_PER_GAUSSIAN_BASE = 11
"""Decoded float32 values per Gaussian besides the SH: mean 3, scale 3, rotation 4, opacity 1."""


def chunk_rows(sh_degree: int) -> int:
    """Rows per chunk so one decoded chunk is about `CHUNK_BYTES` of float32."""
    floats = FLOATS_PER_GAUSSIAN_BASE + 3 * (sh_degree + 1) ** 2
    return max(1, CHUNK_BYTES // (4 * floats))


def _ranges(source: SplatSource) -> list[tuple[int, int]]:
    step = chunk_rows(source.sh_degree)
    return [(start, min(start + step, source.count)) for start in range(0, source.count, step)]


def scan_source(source: SplatSource, *, sample_size: int) -> SplatScan:
    """Validate every Gaussian of `source` like `read_splat` (same refusals and messages)
    holding one chunk at a time; returns the count, SH degree, sample and warnings."""
    index = sample_index(source.count, sample_size)
    nonfinite: dict[str, int] = {}
    degenerate = np.zeros(3, dtype=np.int64)
    max_opacity = 0.0
    parts: list[Gaussians] = []
    for start, stop in _ranges(source):
        chunk = source.rows(start, stop)
        for name, n in nonfinite_counts(chunk).items():
            nonfinite[name] = nonfinite.get(name, 0) + n
        degenerate += degenerate_counts(chunk)
        max_opacity = max(max_opacity, float(np.nan_to_num(chunk.opacities, nan=0.0).max()))
        lo, hi = np.searchsorted(index, [start, stop])
        parts.append(chunk.subset(index[lo:hi] - start))
        del chunk
    raise_nonfinite(nonfinite, source=source.path)
    raise_degenerate((int(degenerate[0]), int(degenerate[1]), int(degenerate[2])), source=str(source.path))
    sample = concat_gaussians(parts)
    extent = splat_extent(sample.means)
    huge = 0
    if extent > 0.0:
        huge = sum(huge_count(source.rows(start, stop).log_scales, extent) for start, stop in _ranges(source))
    return SplatScan(
        source.count, source.sh_degree, sample, warnings_from(source.count, max_opacity, extent, huge)
    )
