"""Every splat file format we read, behind one dispatcher.

`read_splat(path)` picks the reader from the format table (`registry.SPLAT_FORMATS`: the name,
then, for a `.ply`, the header: an INRIA PLY, a PlayCanvas compressed PLY or an RGB-coloured
PLY). Every reader returns the INRIA parameterisation in the PLY's own frame (formats that store
other axes are turned back), and every result passes the same checks as a PLY: finite values and
`scene.sanity.check_splat`. One module per format; the table lists them, what each reads and
writes, and which an upload may carry (`bfields` docs: Bring your own scene, Splat formats).

Why our own readers and not gsply (PyPI, reads PLY, compressed PLY, SPZ; evaluated 0.4.6): on a
1 GB SH-3 PLY (bench/splat_readers.py, 2 shared cores) its raw read was 1.4-1.6x faster than
`read_ply`, which also checks every value; it needs a numba compilation on first use (seconds
per process), returns SPZ in its stored right-up-back axes, reads SOG only with an extra and no
glTF, .splat or checkpoints. The numpy readers here are short, need no JIT, and decode the
`splat-transform` fixtures exactly as `splat-transform` itself does.
"""

from __future__ import annotations

from pathlib import Path

from bayesian_fields_core.errors import input_boundary
from bayesian_fields_core.scene.formats.common import require_finite
from bayesian_fields_core.scene.formats.registry import (
    SPLAT_FORMATS,
    SplatFormat,
    check_upload_name,
    detect,
    splat_format_named,
)
from bayesian_fields_core.scene.formats.source import SplatSource
from bayesian_fields_core.scene.sanity import check_splat
from bayesian_fields_core.scene.types import Gaussians


def splat_format(path: Path) -> str:
    """The format name of a splat path (a `registry.SPLAT_FORMATS` row's name); InputError for a
    known but unread or an unknown format."""
    return detect(path).name


READER_FAILURES: tuple[type[BaseException], ...] = (Exception,)
"""What the splat readers' boundary turns into InputError: every exception. Why not only
`INPUT_FAILURES`: a hostile file reaches code paths no check anticipated (a JSON field of the
wrong type deep in a glTF, a PIL error class), and whatever a reader of an uploaded file raises
is that file's fault; the message keeps the exception's type and text for whoever debugs it."""


def read_splat(path: str | Path, *, max_gaussians: int) -> Gaussians:
    """Load a splat of any supported format, checked like a PLY (module docstring)."""
    path = Path(path)
    fmt = detect(path)
    if fmt.self_checked:
        return fmt.function("reader")(path, max_gaussians=max_gaussians)
    with input_boundary(str(path), what=f"cannot read the {fmt.name} splat", extra=READER_FAILURES):
        if fmt.source is None:
            gaussians = fmt.function("reader")(path, max_gaussians=max_gaussians)
        else:
            with open_source(path, fmt.name, max_gaussians=max_gaussians) as source:
                gaussians = source.rows(0, source.count)
        require_finite(gaussians, source=path)
    check_splat(gaussians, source=str(path))
    return gaussians


def open_source(path: Path, kind: str, *, max_gaussians: int, spill_dir: Path | None = None) -> SplatSource:
    """Open a splat of format `kind` (a table row with a row-range `source`) for reading by row
    range. `spill_dir`: where compressed payloads are inflated to (None: in memory). Raises what
    the reader raises: callers put it inside an `input_boundary(..., extra=READER_FAILURES)`."""
    fmt = splat_format_named(kind)
    if fmt.source is None:
        raise ValueError(f"no row-range reader for splat format {kind!r}")
    return fmt.function("source")(path, max_gaussians, spill_dir=spill_dir)


def check_splat_header(path: str | Path, *, max_gaussians: int) -> str:
    """The cheap check an upload runs before anything else: the format is one we read and, for
    an INRIA PLY, its header is valid. Returns the format name."""
    path = Path(path)
    kind = splat_format(path)
    if kind == "ply":
        from bayesian_fields_core.scene.ply import read_ply_header

        read_ply_header(path, max_gaussians=max_gaussians)
    return kind


__all__ = [
    "READER_FAILURES",
    "SPLAT_FORMATS",
    "SplatFormat",
    "check_splat_header",
    "check_upload_name",
    "open_source",
    "read_splat",
    "splat_format",
]
