"""INRIA-layout PLY whose colour is red/green/blue instead of SH (`ns-export gaussian-splat
--ply-color-mode rgb`, and some viewers' exports).

Everything but the colour is the INRIA layout (x y z, opacity logit, scale_* logs, rot_* w x y z);
colour bytes (uchar, 0..255) or floats (0..1) become the SH DC coefficient and the file is read
as a degree-0 splat. A note is logged: colour-only splats render flatter (no view-dependent
bands), which matters for viewing, not for the pipeline's depth and visibility.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.scene.formats.common import colour_to_dc, gaussians, require_count
from bayesian_fields_core.scene.formats.ply_tables import check_unique, element_tables
from bayesian_fields_core.scene.formats.source import SplatSource
from bayesian_fields_core.scene.ply import read_ply_elements
from bayesian_fields_core.scene.types import Gaussians

log = logging.getLogger(__name__)
RGB = ("red", "green", "blue")
GEOMETRY = ("x", "y", "z", "opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3")


def is_rgb_splat(names: set[str]) -> bool:
    """A splat PLY coloured by red/green/blue (no f_dc_*)."""
    return set(RGB) <= names and set(GEOMETRY) <= names and "f_dc_0" not in names


class RgbPlySource(SplatSource):
    """An opened RGB PLY: its vertex rows checked against the file size, read by range."""

    def __init__(self, path: Path, max_gaussians: int) -> None:
        fmt, elements, offset = read_ply_elements(path)
        check_unique(path, elements, formats="RGB splat PLY")  # the layout was recognised by name
        if not elements or elements[0][0] != "vertex":
            raise InputError("the vertex element must come first", source=str(path))
        n = elements[0][1]
        require_count(n, max_gaussians, source=path)
        super().__init__(path, n, 0)
        self._file = open(path, "rb")  # noqa: SIM115 - closed by close()
        try:
            self._table = element_tables(
                self._file, path, fmt, elements[:1], offset, formats="RGB splat PLY"
            )["vertex"]
        except BaseException:
            self._file.close()
            raise
        red = self._table.dtype["red"]
        self._colour_scale = float(np.iinfo(red).max) if red.kind in "ui" else 1.0
        log.info("%s: colour-only splat (red/green/blue, no SH): it renders flatter", path.name)

    def rows(self, start: int, stop: int) -> Gaussians:
        rows = self._table.read(start, stop)

        def cols(keys: tuple[str, ...]) -> np.ndarray:
            return np.stack([rows[k].astype(np.float32) for k in keys], axis=1)

        colour = cols(RGB) / np.float32(self._colour_scale)
        return gaussians(
            cols(("x", "y", "z")),
            cols(("scale_0", "scale_1", "scale_2")),
            cols(("rot_0", "rot_1", "rot_2", "rot_3")),
            rows["opacity"].astype(np.float32),
            colour_to_dc(colour)[:, None, :],
        )

    def close(self) -> None:
        self._file.close()


def open_rgb_ply(path: Path, max_gaussians: int, *, spill_dir: Path | None = None) -> RgbPlySource:
    """Open an RGB PLY for reading by range (`spill_dir` unused: nothing is inflated)."""
    return RgbPlySource(path, max_gaussians)


def read_rgb_ply(path: Path, max_gaussians: int) -> Gaussians:
    """Read the INRIA geometry and turn the RGB colour into SH DC (module docstring)."""
    with open_rgb_ply(path, max_gaussians) as source:
        return source.rows(0, source.count)
