"""Write a splat in a format other tools open: the export side of `scene.formats`.

One function, `write_splat(path, gaussians, fmt)`, with the writer chosen per format:

  ply             the project's INRIA PLY writer (`scene.ply.write_ply`): every vertex property
                  of the input splat is kept, which gsply's writer (14 standard columns) drops
  compressed-ply  gsply (PyPI): PlayCanvas compressed PLY (SuperSplat, splat-transform)
  spz             gsply: Niantic SPZ v4; gsply stores the values it is given, so the Gaussians
                  are first turned into SPZ's right-up-back axes (the reader turns them back)
  splat           the project's antimatter15 writer (no Python library writes `.splat`;
                  degree-0 colour only, as the format holds)
  glb             the project's glTF writer (`gltf_write`: no Python library writes
                  `KHR_gaussian_splatting`), laid out as splat-transform's own `.glb`
  sog             the project's SOG writer (`sog_write`: no Python library writes SOG; degree-0
                  colour only), the inverse of the SOG reader
Formats are named by the `EXPORT_FORMATS` keys, file names end in their `SUFFIXES`.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.scene.types import Gaussians

EXPORT_FORMATS = {
    "ply": "3DGS PLY (INRIA layout, every attribute of the input splat)",
    "compressed-ply": "PlayCanvas compressed PLY (gsply)",
    "spz": "Niantic SPZ v4 (gsply)",
    "splat": "antimatter15 .splat (degree-0 colour only)",
    "glb": "binary glTF with KHR_gaussian_splatting",
    "sog": "PlayCanvas SOG v2 (degree-0 colour only)",
}
"""The formats `write_splat` writes, with what each is."""

SUFFIXES = {
    "ply": ".ply",
    "compressed-ply": ".compressed.ply",
    "spz": ".spz",
    "splat": ".splat",
    "glb": ".glb",
    "sog": ".sog",
}

log = logging.getLogger(__name__)
DEGREE_ZERO_ONLY = ("splat", "sog")
"""Formats written with the degree-0 colour only (`write_splat` says so when bands are dropped)."""

SPZ_VERSION = 4
PLY_TO_RUB = np.diag([1.0, -1.0, -1.0])
"""SPZ stores right-up-back; a 3DGS PLY is right-down-forward: 180 degrees about x (its own inverse)."""


def check_format(fmt: str) -> str:
    """`fmt` if `write_splat` writes it, else an InputError naming the supported formats."""
    if fmt in EXPORT_FORMATS:
        return fmt
    raise InputError(f"unknown format {fmt!r}; use one of: {', '.join(EXPORT_FORMATS)}")


def write_splat(path: str | Path, gaussians: Gaussians, fmt: str) -> Path:
    """Write `gaussians` (a 3DGS PLY's frame and parameterisation) to `path` as `fmt`; returns
    the path. The suffix is the caller's choice (`SUFFIXES` gives the usual one)."""
    fmt = check_format(fmt)
    path = Path(path)
    if len(gaussians) == 0:
        raise InputError("nothing to export: the selection holds no Gaussians", source=str(path))
    if fmt in DEGREE_ZERO_ONLY and gaussians.sh_degree > 0:
        log.warning(
            "%s: %s holds the degree-0 colour only; SH degrees 1-%d dropped",
            path.name,
            fmt,
            gaussians.sh_degree,
        )
    if fmt == "ply":
        from bayesian_fields_core.scene.ply import write_ply

        write_ply(path, gaussians)
    elif fmt == "splat":
        from bayesian_fields_core.scene.formats.antimatter import write_antimatter

        write_antimatter(path, gaussians)
    elif fmt == "glb":
        from bayesian_fields_core.scene.formats.gltf_write import write_glb

        write_glb(path, gaussians)
    elif fmt == "sog":
        from bayesian_fields_core.scene.formats.sog_write import write_sog

        write_sog(path, gaussians)
    else:
        _write_gsply(path, gaussians, compressed=fmt == "compressed-ply")
    return path


def _write_gsply(path: Path, gaussians: Gaussians, *, compressed: bool) -> None:
    """Compressed PLY or SPZ through gsply (imported here: it compiles with numba on first use)."""
    import gsply

    from bayesian_fields_core.scene.formats.common import rotate_axes

    g = gaussians if compressed else rotate_axes(gaussians, PLY_TO_RUB)
    data = gsply.GSData(
        means=np.ascontiguousarray(g.means, dtype=np.float32),
        scales=np.ascontiguousarray(g.log_scales, dtype=np.float32),
        quats=np.ascontiguousarray(g.quats, dtype=np.float32),
        opacities=np.ascontiguousarray(g.opacity_logits, dtype=np.float32),
        sh0=np.ascontiguousarray(g.sh[:, 0, :], dtype=np.float32),
        shN=np.ascontiguousarray(g.sh[:, 1:, :], dtype=np.float32),
    )
    if compressed:
        # gsply appends `.compressed.ply` unless the name already ends in it; write where asked
        gsply.plywrite(path, data, compressed=True)
        written = (
            path if path.name.endswith(".compressed.ply") else path.with_name(path.stem + ".compressed.ply")
        )
        if written != path:
            written.replace(path)
    else:
        gsply.write_spz(path, data, version=SPZ_VERSION)
