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
from bayesian_fields_core.scene.ply import read_ply_elements
from bayesian_fields_core.scene.types import Gaussians

log = logging.getLogger(__name__)
RGB = ("red", "green", "blue")
GEOMETRY = ("x", "y", "z", "opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3")


def is_rgb_splat(names: set[str]) -> bool:
    """A splat PLY coloured by red/green/blue (no f_dc_*)."""
    return set(RGB) <= names and set(GEOMETRY) <= names and "f_dc_0" not in names


def read_rgb_ply(path: Path, max_gaussians: int) -> Gaussians:
    """Read the INRIA geometry and turn the RGB colour into SH DC (module docstring)."""
    fmt, elements, offset = read_ply_elements(path)
    if fmt != "binary_little_endian" and fmt != "binary_big_endian":
        raise InputError(f"RGB splat PLY must be binary, not {fmt}", source=str(path))
    order = "<" if fmt == "binary_little_endian" else ">"
    names = [e[0] for e in elements]
    if names[0] != "vertex":
        raise InputError("the vertex element must come first", source=str(path))
    _, n, props = elements[0]
    if any(p[1] == "list" for p in props):
        raise InputError("vertex element has list properties; a splat has none", source=str(path))
    require_count(n, max_gaussians, source=path)
    dtype = np.dtype([(p[0], order + p[1]) for p in props])
    with open(path, "rb") as f:
        f.seek(offset)
        rows = np.fromfile(f, dtype=dtype, count=n)
    if rows.shape[0] != n:
        raise InputError(f"truncated vertex data: expected {n} rows, got {rows.shape[0]}", source=str(path))

    def cols(keys: tuple[str, ...]) -> np.ndarray:
        return np.stack([rows[k].astype(np.float32) for k in keys], axis=1)

    colour = cols(RGB)
    if dtype["red"].kind in "ui":
        colour /= float(np.iinfo(dtype["red"]).max)
    log.info("%s: colour-only splat (red/green/blue, no SH): it renders flatter", path.name)
    return gaussians(
        cols(("x", "y", "z")),
        cols(("scale_0", "scale_1", "scale_2")),
        cols(("rot_0", "rot_1", "rot_2", "rot_3")),
        rows["opacity"].astype(np.float32),
        colour_to_dc(colour)[:, None, :],
    )
