"""Compressed PLY and SPZ written through gsply (PyPI), the two export formats a library writes.

gsply is imported inside the writers: it compiles with numba on first use, which only an export
of these formats should pay. gsply stores the values it is given, so SPZ's Gaussians are first
turned into SPZ's right-up-back axes (the project's reader turns them back).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from bayesian_fields_core.scene.formats.common import rotate_axes
from bayesian_fields_core.scene.types import Gaussians

SPZ_VERSION = 4
PLY_TO_RUB = np.diag([1.0, -1.0, -1.0])
"""SPZ stores right-up-back; a 3DGS PLY is right-down-forward: 180 degrees about x (its own inverse)."""


def write_compressed_ply(path: Path, gaussians: Gaussians) -> None:
    """PlayCanvas compressed PLY (SuperSplat, splat-transform) at exactly `path`."""
    import gsply

    # gsply appends `.compressed.ply` unless the name already ends in it; write where asked
    gsply.plywrite(path, _gs_data(gaussians), compressed=True)
    written = path if path.name.endswith(".compressed.ply") else path.with_name(path.stem + ".compressed.ply")
    if written != path:
        written.replace(path)


def write_spz(path: Path, gaussians: Gaussians) -> None:
    """Niantic SPZ v4, in SPZ's right-up-back axes."""
    import gsply

    gsply.write_spz(path, _gs_data(rotate_axes(gaussians, PLY_TO_RUB)), version=SPZ_VERSION)


def _gs_data(g: Gaussians) -> Any:
    """The Gaussians as gsply's `GSData` (contiguous float32 arrays, SH split as gsply keeps it)."""
    import gsply

    return gsply.GSData(
        means=np.ascontiguousarray(g.means, dtype=np.float32),
        scales=np.ascontiguousarray(g.log_scales, dtype=np.float32),
        quats=np.ascontiguousarray(g.quats, dtype=np.float32),
        opacities=np.ascontiguousarray(g.opacity_logits, dtype=np.float32),
        sh0=np.ascontiguousarray(g.sh[:, 0, :], dtype=np.float32),
        shN=np.ascontiguousarray(g.sh[:, 1:, :], dtype=np.float32),
    )
