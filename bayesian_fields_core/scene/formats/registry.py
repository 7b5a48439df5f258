"""The splat format table: every fact about a splat format, written once.

The loader (`formats.read_splat`), the layout detection (`scene.layout`: which files of a folder
may be the splat), the service's upload check (`formats.check_upload_name`, the scenes route's
OpenAPI description), the error messages that list what we read and the docs' format table
(`bfields` docs build, `markdown_table`) and the export (`formats.write`, `bfields export
--format`: a row's `export`) all read `SPLAT_FORMATS`. Adding a format is adding a row here and
its reader (and writer) module beside this one, as adding a model kind is a row of
`perception/kinds.py`.

A row names its functions by import path (``module:function``), imported on first use, so
importing the table (the API does, to describe its upload field) loads no reader.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.scene.formats.common import convert_command
from bayesian_fields_core.scene.types import Gaussians

FORMATS_MODULE = "bayesian_fields_core.scene.formats"


def load_function(target: str) -> Callable[..., Any]:
    """The function named by ``module:function``, imported now (a row's functions load on use)."""
    module, _, attribute = target.partition(":")
    return getattr(importlib.import_module(module), attribute)


@dataclass(frozen=True)
class SplatExport:
    """How `bfields export` writes a format (`formats.write.write_splat`).

    name: the `--format` value ('compressed-ply'), which is not always the row's name.
    suffix: the file name ending an export gets by default ('.compressed.ply').
    description: what the file is, said where the formats are listed.
    writer: ``module:function`` of `(path, gaussians)`, Gaussians in a 3DGS PLY's frame and
        parameterisation (a writer turns them into its format's axes).
    position: where the format stands in `--format`'s list and messages (ply first: the default).
    degree_zero_only: the format holds the degree-0 colour only (the export warns when it drops
        higher SH bands).
    """

    name: str
    suffix: str
    description: str
    writer: str
    position: int
    degree_zero_only: bool = False

    def write(self, path: Path, gaussians: Gaussians) -> None:
        """Write `gaussians` to `path` with this format's writer."""
        load_function(self.writer)(path, gaussians)


@dataclass(frozen=True)
class SplatFormat:
    """One splat format: how it is recognised, read and written, and what a user should know.

    name: the format's id ('ply', 'spz', ...): `read_splat`'s kind, the upload report's format.
    title: what people call it, for the docs' table.
    suffixes: lower-case name endings that may be this format ('.ply'); several formats may
        share one, and `sniff` tells them apart.
    file_names: exact lower-case file names that are this format (SOG's `meta.json`).
    folder: a folder is this format (an unzipped SOG).
    sniff: ``module:function`` of `(path) -> bool`, whether the file's content is this format;
        None: the name decides. Among the formats a name matches, those with a sniff are asked
        first, in table order, and the first without one takes the rest.
    source: ``module:function`` of the row-range opener `(path, max_gaussians, *, spill_dir) ->
        SplatSource`, for formats read in row ranges (the upload check walks them so).
    reader: ``module:function`` of `(path, *, max_gaussians) -> Gaussians` for a format read whole.
        Neither `source` nor `reader`: a known format we refuse, naming the converter.
    self_checked: the reader refuses non-finite values and degenerate splats itself, with its own
        messages (the INRIA PLY's); every other reader's result is checked by `read_splat`.
    export: how `bfields export` writes the format (`SplatExport`); None: it is not written.
    upload_refusal: why an upload may not carry a format we read, and what to do instead (a
        checkpoint is a pickle stream: CLI only); None: an upload may carry it.
    notes: what the reader does beyond decoding (axes, bands dropped), for the docs' table.
    """

    name: str
    title: str
    suffixes: tuple[str, ...] = ()
    file_names: tuple[str, ...] = ()
    folder: bool = False
    sniff: str | None = None
    source: str | None = None
    reader: str | None = None
    self_checked: bool = False
    export: SplatExport | None = None
    upload_refusal: str | None = None
    notes: str = ""

    @property
    def upload(self) -> bool:
        """An upload may carry it: we read it and the row names no reason to refuse it."""
        return self.readable and self.upload_refusal is None

    @property
    def writer(self) -> str | None:
        """``module:function`` of the export's writer (`function('writer')`); None: not written."""
        return self.export.writer if self.export else None

    @property
    def readable(self) -> bool:
        """We read it (else it is refused with the command that converts it)."""
        return self.source is not None or self.reader is not None

    def matches_name(self, path: Path) -> bool:
        """The name (or being a folder) says the file may be this format."""
        name = path.name.lower()
        return (self.folder and path.is_dir()) or name in self.file_names or name.endswith(self.suffixes)

    def function(self, field: str) -> Callable[..., Any]:
        """The function a row names in `field` ('sniff', 'source', 'reader', 'writer')."""
        target = getattr(self, field)
        if target is None:
            raise ValueError(f"splat format {self.name!r} has no {field}")
        return load_function(target)


SPLAT_FORMATS: tuple[SplatFormat, ...] = (
    SplatFormat(
        "compressed_ply",
        "PlayCanvas / SuperSplat compressed PLY (`.compressed.ply`)",
        suffixes=(".ply",),
        sniff=f"{FORMATS_MODULE}.sniff:is_compressed_ply_file",
        source=f"{FORMATS_MODULE}.compressed_ply:open_compressed_ply",
        export=SplatExport(
            "compressed-ply",
            ".compressed.ply",
            "PlayCanvas compressed PLY (gsply)",
            f"{FORMATS_MODULE}.gsply_write:write_compressed_ply",
            position=2,
        ),
        notes="chunked, quantised; told from an INRIA PLY by its `packed_*` properties",
    ),
    SplatFormat(
        "rgb_ply",
        "PLY coloured by red/green/blue",
        suffixes=(".ply",),
        sniff=f"{FORMATS_MODULE}.sniff:is_rgb_ply_file",
        source=f"{FORMATS_MODULE}.ply_rgb:open_rgb_ply",
        notes="an INRIA layout with 8-bit colours instead of SH; degree 0",
    ),
    SplatFormat(
        "ply",
        "INRIA 3D Gaussian Splatting PLY",
        suffixes=(".ply",),
        reader="bayesian_fields_core.scene.ply:read_ply",
        self_checked=True,
        export=SplatExport(
            "ply",
            ".ply",
            "3DGS PLY (INRIA layout, every attribute of the input splat)",
            "bayesian_fields_core.scene.ply:write_ply",
            position=1,
        ),
        notes="the reference layout; every other format is turned into it",
    ),
    SplatFormat(
        "spz",
        "Niantic SPZ (`.spz`, v1-4)",
        suffixes=(".spz",),
        source=f"{FORMATS_MODULE}.spz:open_spz",
        export=SplatExport(
            "spz", ".spz", "Niantic SPZ v4 (gsply)", f"{FORMATS_MODULE}.gsply_write:write_spz", position=3
        ),
        notes="its right-up-back axes turned back to the PLY's",
    ),
    SplatFormat(
        "sog",
        "PlayCanvas SOG v2 (`.sog` zip, or a folder with `meta.json`)",
        suffixes=(".sog",),
        file_names=("meta.json",),
        folder=True,
        source=f"{FORMATS_MODULE}.sog:open_sog",
        export=SplatExport(
            "sog",
            ".sog",
            "PlayCanvas SOG v2 (degree-0 colour only)",
            f"{FORMATS_MODULE}.sog_write:write_sog",
            position=6,
            degree_zero_only=True,
        ),
        notes="SH bands above those it stores are dropped",
    ),
    SplatFormat(
        "splat",
        "antimatter15 `.splat`",
        suffixes=(".splat",),
        source=f"{FORMATS_MODULE}.antimatter:open_antimatter",
        export=SplatExport(
            "splat",
            ".splat",
            "antimatter15 .splat (degree-0 colour only)",
            f"{FORMATS_MODULE}.antimatter:write_antimatter",
            position=4,
            degree_zero_only=True,
        ),
        notes="degree-0 colour only",
    ),
    SplatFormat(
        "gltf",
        "glTF with `KHR_gaussian_splatting` (`.glb`, `.gltf`)",
        suffixes=(".glb", ".gltf"),
        source=f"{FORMATS_MODULE}.gltf:open_gltf",
        export=SplatExport(
            "glb",
            ".glb",
            "binary glTF with KHR_gaussian_splatting",
            f"{FORMATS_MODULE}.gltf_write:write_glb",
            position=5,
        ),
        notes="the JSON is validated field by field",
    ),
    SplatFormat(
        "checkpoint",
        "gsplat checkpoint (`ckpts/ckpt_<step>.pt`)",
        suffixes=(".pt",),
        reader=f"{FORMATS_MODULE}.checkpoint:read_checkpoint",
        upload_refusal="the service does not accept checkpoints (.pt); run `bfields submit` on the gsplat "
        "result folder (it converts the checkpoint to a .ply first) or `bfields run` locally",
        notes="CLI only (torch.load with weights_only; a pickle stream the service never opens); "
        "in the trainer's frame",
    ),
    SplatFormat(
        "ksplat",
        "mkkellogg `.ksplat`",
        suffixes=(".ksplat",),
        notes="refused with the command that converts it (no specification outside its viewer)",
    ),
    SplatFormat(
        "lcc",
        "XGRIDS `.lcc`",
        suffixes=(".lcc",),
        notes="refused with the command that converts it",
    ),
)


def splat_format_named(name: str) -> SplatFormat:
    """The row called `name`; KeyError naming the known ones otherwise."""
    for fmt in SPLAT_FORMATS:
        if fmt.name == name:
            return fmt
    raise KeyError(f"unknown splat format {name!r}; known: {', '.join(f.name for f in SPLAT_FORMATS)}")


def export_formats() -> tuple[SplatExport, ...]:
    """What `bfields export --format` writes, in the order its help and messages list them."""
    return tuple(sorted((fmt.export for fmt in SPLAT_FORMATS if fmt.export), key=lambda e: e.position))


def is_splat_candidate(path: Path) -> bool:
    """A file (or SOG meta.json) the layout detection counts as a splat: any row's name matches,
    refused formats included, so a lone `.ksplat` is refused with its converter, not 'no splat'."""
    name = path.name.lower()
    return any(
        (path.is_file() and name.endswith(fmt.suffixes)) or name in fmt.file_names for fmt in SPLAT_FORMATS
    )


def detect(path: Path) -> SplatFormat:
    """The format of `path` by name, then content where names are shared.

    InputError for a known format we do not read (naming the converter) and for a name no row
    matches (listing what we read)."""
    named = [fmt for fmt in SPLAT_FORMATS if (fmt.folder if path.is_dir() else fmt.matches_name(path))]
    sniffed = [fmt for fmt in named if fmt.sniff is not None]
    found = next((fmt for fmt in sniffed if fmt.function("sniff")(path)), None)
    if found is None:
        found = next((fmt for fmt in named if fmt.sniff is None), None)
    if found is None:
        raise InputError(
            f"not a splat format we read ({accepted_names()}); if splat-transform reads it, "
            f"convert it: {convert_command(path)}",
            source=str(path),
        )
    if not found.readable:
        raise InputError(
            f"{path.suffix} splats are not read; convert it first: {convert_command(path)}", source=str(path)
        )
    return found


def accepted_names(*, upload: bool = False) -> str:
    """'.ply, .spz, .sog, SOG meta.json, .splat, .glb, .gltf, .pt': the names we read (`upload`:
    the suffixes an upload may carry), in table order, each once, for messages and descriptions."""
    names: list[str] = []
    for fmt in SPLAT_FORMATS:
        if fmt.upload or (fmt.readable and not upload):
            names += [s for s in fmt.suffixes if s not in names]
            if not upload:  # an upload carries one file: a folder's meta.json is not one
                names += [f"SOG {n}" for n in fmt.file_names if f"SOG {n}" not in names]
    return ", ".join(names)


def check_upload_name(name: str) -> None:
    """Refuse, by name, a splat an upload cannot carry: a format the table marks CLI only (a
    checkpoint: a pickle stream the service never opens), a format we do not read, or no known
    name. The message names the converter or the local route."""
    path, lower = Path(name), name.lower()
    named = [fmt for fmt in SPLAT_FORMATS if lower.endswith(fmt.suffixes)]  # by name only: never stat it
    for fmt in named:
        if fmt.readable and fmt.upload_refusal:
            raise InputError(f"{name!r}: {fmt.upload_refusal}", source="splat")
    if named and not any(fmt.upload for fmt in named):
        raise InputError(
            f"{name!r}: {path.suffix} splats are not read; convert it: {convert_command(path)}",
            source="splat",
        )
    if not named:
        raise InputError(
            f"{name!r} is not a splat file we read ({accepted_names(upload=True)}); "
            f"if it is a splat, convert it: {convert_command(path)}",
            source="splat",
        )


def upload_description() -> str:
    """The upload form's `splat` field, as the API's OpenAPI schema describes it."""
    local = [s for fmt in SPLAT_FORMATS if fmt.readable and not fmt.upload for s in fmt.suffixes]
    unread = [s for fmt in SPLAT_FORMATS if not fmt.readable for s in fmt.suffixes]
    return (
        f"The splat: {accepted_names(upload=True)} (every PLY flavour: INRIA, RGB-coloured, "
        f"compressed); not {', '.join(local)} (CLI only); {', '.join(unread)} are refused with "
        "the command that converts them."
    )


def markdown_table() -> str:
    """The docs' format table, one row per format (what `docs/_build/hooks.py` writes)."""
    lines = ["| format | names | read | written | upload | notes |", "|---|---|---|---|---|---|"]
    for fmt in SPLAT_FORMATS:
        names = ", ".join([f"`{s}`" for s in fmt.suffixes] + [f"`{n}`" for n in fmt.file_names])
        if fmt.folder:
            names += ", a folder"
        cells = (
            fmt.title,
            names,
            "yes" if fmt.readable else "no (refused, names the converter)",
            "yes" if fmt.export else "",
            "yes" if fmt.upload else "no",
            fmt.notes,
        )
        lines.append("| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |")
    return "\n".join(lines) + "\n"
