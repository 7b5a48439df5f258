"""The `.splat` format of antimatter15's WebGL viewer (also read by most web viewers).

32 bytes per Gaussian, no header: position float32 x3, scale float32 x3 (linear std), colour
uint8 RGBA (RGB = 255 * (0.5 + SH_C0 * f_dc), A = 255 * opacity), rotation uint8 x4
(w, x, y, z, each 128 * q + 128, normalised quaternion). No SH bands, no axis change: the
converter copies the PLY's frame. The reader has a writer beside it because no tool we can run
here writes the format; `splat-transform` reads our files back as its check.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.scene.formats.common import SH_C0, colour_to_dc, gaussians, logit, require_count
from bayesian_fields_core.scene.formats.source import RecordTable, SplatSource
from bayesian_fields_core.scene.types import Gaussians

ROW = np.dtype([("position", "<f4", 3), ("scale", "<f4", 3), ("rgba", "u1", 4), ("rot", "u1", 4)])


class AntimatterSource(SplatSource):
    """An opened `.splat`: its size checked against the row size, rows read by range."""

    def __init__(self, path: Path, max_gaussians: int) -> None:
        size = path.stat().st_size
        if size % ROW.itemsize:
            raise InputError(
                f"{size} bytes is not a multiple of the {ROW.itemsize}-byte .splat row", source=str(path)
            )
        n = size // ROW.itemsize
        require_count(n, max_gaussians, source=path)
        super().__init__(path, n, 0)
        self._file = open(path, "rb")  # noqa: SIM115 - closed by close()
        self._table = RecordTable(self._file, 0, ROW, n, what=".splat data", source=path)

    def rows(self, start: int, stop: int) -> Gaussians:
        rows = self._table.read(start, stop)
        with np.errstate(divide="ignore", invalid="ignore"):
            log_scales = np.log(rows["scale"])
        quats = (rows["rot"].astype(np.float32) - 128.0) / 128.0
        rgba = rows["rgba"].astype(np.float32) / 255.0
        return gaussians(
            rows["position"], log_scales, quats, logit(rgba[:, 3]), colour_to_dc(rgba[:, :3])[:, None, :]
        )

    def close(self) -> None:
        self._file.close()


def open_antimatter(path: Path, max_gaussians: int, *, spill_dir: Path | None = None) -> AntimatterSource:
    """Open a `.splat` for reading by range (`spill_dir` unused: nothing is inflated)."""
    return AntimatterSource(path, max_gaussians)


def read_antimatter(path: Path, max_gaussians: int) -> Gaussians:
    """Decode a whole `.splat` file (module docstring)."""
    with open_antimatter(path, max_gaussians) as source:
        return source.rows(0, source.count)


def write_antimatter(path: Path, g: Gaussians) -> None:
    """Write `g` as a `.splat` (degree-0 colour only), rows in the file order of `g`."""
    rows = np.zeros(len(g), dtype=ROW)
    rows["position"] = g.means
    rows["scale"] = np.exp(g.log_scales)
    colour = np.clip(0.5 + SH_C0 * g.sh[:, 0, :], 0.0, 1.0)
    rows["rgba"][:, :3] = np.round(colour * 255.0)
    rows["rgba"][:, 3] = np.round(np.clip(g.opacities, 0.0, 1.0) * 255.0)
    q = g.quats / np.linalg.norm(g.quats, axis=1, keepdims=True)
    rows["rot"] = np.clip(np.round(q * 128.0 + 128.0), 0, 255)
    rows.tofile(path)
