"""Every splat file format we read, behind one dispatcher.

`read_splat(path)` picks the reader from the name and, for `.ply`, from the header: an INRIA
PLY (`scene.ply`), a PlayCanvas compressed PLY (`packed_*` properties), or an INRIA PLY
coloured by red/green/blue. Every reader returns the INRIA parameterisation in the PLY's own
frame (formats that store other axes are turned back), and every result passes the same checks
as a PLY: finite values and `scene.sanity.check_splat`. One module per format:

  .ply                 INRIA layout (scene/ply.py), compressed (compressed_ply), RGB (ply_rgb)
  .spz                 Niantic SPZ v1-4 (spz)
  .sog, meta.json      PlayCanvas SOG v2, zip or folder (sog)
  .splat               antimatter15 (antimatter)
  .glb, .gltf          KHR_gaussian_splatting (gltf)
  ckpt_<step>.pt       gsplat checkpoint, weights_only torch.load, CLI only (checkpoint)
  .ksplat              refused with the command that converts it (no reader: the format has no
                       specification outside its viewer's source, and splat-transform reads it)

Why our own readers and not gsply (PyPI, reads PLY, compressed PLY, SPZ; evaluated 0.4.6): on a
1 GB SH-3 PLY (bench/splat_readers.py, 2 shared cores) its raw read was 1.4-1.6x faster than
`read_ply`, which also checks every value; it needs a numba compilation on first use (seconds
per process), returns SPZ in its stored right-up-back axes, reads SOG only with an extra and no
glTF, .splat or checkpoints. The numpy readers here are short, need no JIT, and decode the
`splat-transform` fixtures exactly as `splat-transform` itself does.
"""

from __future__ import annotations

from pathlib import Path

from bayesian_fields_core.errors import InputError, input_boundary
from bayesian_fields_core.scene.formats.common import convert_command, require_finite
from bayesian_fields_core.scene.formats.source import SplatSource
from bayesian_fields_core.scene.sanity import check_splat
from bayesian_fields_core.scene.types import Gaussians

SPLAT_SUFFIXES = (".ply", ".spz", ".sog", ".splat", ".glb", ".gltf", ".pt")
"""Suffixes of the files `find_splat_file` considers (`.compressed.ply` ends in `.ply`)."""
REFUSED_SUFFIXES = (".ksplat", ".lcc")
"""Known splat formats we do not read; refused naming the converter."""
SERVICE_REFUSED = (".pt",)
"""Read by the CLI but never accepted by an upload (a checkpoint is a pickle stream)."""
SOG_META = "meta.json"


def splat_format(path: Path) -> str:
    """The format name of a splat path ('ply', 'compressed_ply', 'rgb_ply', 'spz', 'sog',
    'splat', 'gltf', 'checkpoint'); InputError for a known but unread or an unknown format."""
    name = path.name.lower()
    if path.is_dir() or name == SOG_META or name.endswith(".sog"):
        return "sog"
    if name.endswith(".ply"):
        return _ply_kind(path)
    for suffix, kind in ((".spz", "spz"), (".splat", "splat"), (".glb", "gltf"), (".gltf", "gltf")):
        if name.endswith(suffix):
            return kind
    if name.endswith(".pt"):
        return "checkpoint"
    if name.endswith(REFUSED_SUFFIXES):
        raise InputError(
            f"{path.suffix} splats are not read; convert it first: {convert_command(path)}", source=str(path)
        )
    raise InputError(
        f"not a splat format we read ({', '.join(SPLAT_SUFFIXES)}, SOG meta.json); "
        f"if splat-transform reads it, convert it: {convert_command(path)}",
        source=str(path),
    )


def _ply_kind(path: Path) -> str:
    from bayesian_fields_core.scene.formats.compressed_ply import is_compressed_ply
    from bayesian_fields_core.scene.formats.ply_rgb import is_rgb_splat
    from bayesian_fields_core.scene.ply import read_ply_elements

    with input_boundary(str(path), what="cannot read PLY header", extra=READER_FAILURES):
        _, elements, _ = read_ply_elements(path)
    if is_compressed_ply(elements):
        return "compressed_ply"
    names = {p[0] for name, _, props in elements if name == "vertex" for p in props}
    if is_rgb_splat(names):
        return "rgb_ply"
    return "ply"


READER_FAILURES: tuple[type[BaseException], ...] = (Exception,)
"""What the splat readers' boundary turns into InputError: every exception. Why not only
`INPUT_FAILURES`: a hostile file reaches code paths no check anticipated (a JSON field of the
wrong type deep in a glTF, a PIL error class), and whatever a reader of an uploaded file raises
is that file's fault; the message keeps the exception's type and text for whoever debugs it."""


def read_splat(path: str | Path, *, max_gaussians: int) -> Gaussians:
    """Load a splat of any supported format, checked like a PLY (module docstring)."""
    path = Path(path)
    kind = splat_format(path)
    if kind == "ply":
        from bayesian_fields_core.scene.ply import read_ply

        return read_ply(path, max_gaussians=max_gaussians)
    if kind == "checkpoint":
        from bayesian_fields_core.scene.formats.checkpoint import read_checkpoint

        with input_boundary(str(path), what="cannot read the checkpoint", extra=READER_FAILURES):
            gaussians = read_checkpoint(path, max_gaussians)
    else:
        with input_boundary(str(path), what=f"cannot read the {kind} splat", extra=READER_FAILURES):
            with open_source(path, kind, max_gaussians=max_gaussians) as source:
                gaussians = source.rows(0, source.count)
    with input_boundary(str(path), what=f"cannot read the {kind} splat", extra=READER_FAILURES):
        require_finite(gaussians, source=path)
    check_splat(gaussians, source=str(path))
    return gaussians


def open_source(path: Path, kind: str, *, max_gaussians: int, spill_dir: Path | None = None) -> SplatSource:
    """Open a splat of format `kind` (not an INRIA PLY or a checkpoint) for reading by row range.
    `spill_dir`: where compressed payloads are inflated to (None: in memory). Raises what the
    reader raises: callers put it inside an `input_boundary(..., extra=READER_FAILURES)`."""
    return _opener(kind)(path, max_gaussians, spill_dir=spill_dir)


def _opener(kind: str):  # noqa: ANN202 - one of the openers below, all (Path, int, *, spill_dir) -> SplatSource
    if kind == "compressed_ply":
        from bayesian_fields_core.scene.formats.compressed_ply import open_compressed_ply

        return open_compressed_ply
    if kind == "rgb_ply":
        from bayesian_fields_core.scene.formats.ply_rgb import open_rgb_ply

        return open_rgb_ply
    if kind == "spz":
        from bayesian_fields_core.scene.formats.spz import open_spz

        return open_spz
    if kind == "sog":
        from bayesian_fields_core.scene.formats.sog import open_sog

        return open_sog
    if kind == "splat":
        from bayesian_fields_core.scene.formats.antimatter import open_antimatter

        return open_antimatter
    if kind == "gltf":
        from bayesian_fields_core.scene.formats.gltf import open_gltf

        return open_gltf
    raise ValueError(f"no row-range reader for splat format {kind!r}")


def check_upload_name(name: str) -> None:
    """Refuse, by name, a splat an upload cannot carry: a checkpoint (a pickle stream the service
    never opens), a format we do not read, or no known suffix. The message names the converter."""
    lower = name.lower()
    path = Path(name)
    if lower.endswith(SERVICE_REFUSED):
        raise InputError(
            f"{name!r}: the service does not accept checkpoints (.pt); run `bfields submit` on the "
            "gsplat result folder (it converts the checkpoint to a .ply first) or `bfields run` locally",
            source="splat",
        )
    if lower.endswith(REFUSED_SUFFIXES):
        raise InputError(
            f"{name!r}: {path.suffix} splats are not read; convert it: {convert_command(path)}",
            source="splat",
        )
    if not lower.endswith(SPLAT_SUFFIXES):
        raise InputError(
            f"{name!r} is not a splat file we read (.ply, .compressed.ply, .spz, .sog, .splat, .glb, .gltf); "
            f"if it is a splat, convert it: {convert_command(path)}",
            source="splat",
        )


def check_splat_header(path: str | Path, *, max_gaussians: int) -> str:
    """The cheap check an upload runs before anything else: the format is one we read and, for
    an INRIA PLY, its header is valid. Returns the format name."""
    path = Path(path)
    kind = splat_format(path)
    if kind == "ply":
        from bayesian_fields_core.scene.ply import read_ply_header

        read_ply_header(path, max_gaussians=max_gaussians)
    return kind
