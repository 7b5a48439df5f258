"""Write a splat in a format other tools open: the export side of `scene.formats`.

One function, `write_splat(path, gaussians, fmt)`. What it writes, each format's `--format` name,
file suffix, description and writer, is the `export` of its row in the format table
(`registry.SPLAT_FORMATS`), so adding an export format is adding it there:

  ply             the project's INRIA PLY writer (`scene.ply.write_ply`): every vertex property
                  of the input splat is kept, which gsply's writer (14 standard columns) drops
  compressed-ply  gsply (PyPI): PlayCanvas compressed PLY (SuperSplat, splat-transform)
  spz             gsply: Niantic SPZ v4, in SPZ's right-up-back axes (`gsply_write`)
  splat           the project's antimatter15 writer (no Python library writes `.splat`;
                  degree-0 colour only, as the format holds)
  glb             the project's glTF writer (`gltf_write`: no Python library writes
                  `KHR_gaussian_splatting`), laid out as splat-transform's own `.glb`
  sog             the project's SOG writer (`sog_write`: no Python library writes SOG; degree-0
                  colour only), the inverse of the SOG reader
`EXPORT_FORMATS` and `SUFFIXES` are the table's exports keyed by `--format` name.
"""

from __future__ import annotations

import logging
from pathlib import Path

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.scene.formats.registry import SplatExport, export_formats
from bayesian_fields_core.scene.types import Gaussians

EXPORTS: dict[str, SplatExport] = {export.name: export for export in export_formats()}
"""The formats `write_splat` writes, by `--format` name, in the order the CLI lists them."""

EXPORT_FORMATS = {name: export.description for name, export in EXPORTS.items()}
"""The formats `write_splat` writes, with what each is."""

SUFFIXES = {name: export.suffix for name, export in EXPORTS.items()}
"""The file name ending each format's export gets by default."""

log = logging.getLogger(__name__)


def check_format(fmt: str) -> str:
    """`fmt` if `write_splat` writes it, else an InputError naming the supported formats."""
    if fmt in EXPORTS:
        return fmt
    raise InputError(f"unknown format {fmt!r}; use one of: {', '.join(EXPORTS)}")


def write_splat(path: str | Path, gaussians: Gaussians, fmt: str) -> Path:
    """Write `gaussians` (a 3DGS PLY's frame and parameterisation) to `path` as `fmt`; returns
    the path. The suffix is the caller's choice (`SUFFIXES` gives the usual one)."""
    export = EXPORTS[check_format(fmt)]
    path = Path(path)
    if len(gaussians) == 0:
        raise InputError("nothing to export: the selection holds no Gaussians", source=str(path))
    if export.degree_zero_only and gaussians.sh_degree > 0:
        log.warning(
            "%s: %s holds the degree-0 colour only; SH degrees 1-%d dropped",
            path.name,
            fmt,
            gaussians.sh_degree,
        )
    export.write(path, gaussians)
    return path
