"""The camera format table: every fact about a camera file format, written once.

The layout detection (`scene.layout`: which file of a folder holds the cameras, what a
scene.yaml's `cameras` names, whether images come from a folder, whether intrinsics follow 3DGS's
resize, whether the poses carry nerfstudio's `applied_transform`), the trainer run folders
(`scene.trainer_runs`: where a COLMAP model may lie), the loader (`scene.loader`: which reader),
the messages that list what we read and the docs' camera table (`markdown_table`, written into
docs/guide/your-scene.md at build time) all read `CAMERA_FORMATS`. Adding a camera format is
adding a row here and its reader, as adding a splat format is a row of `formats/registry.py`.

A row names its reader by import path (``module:function``), imported on first use, so importing
the table (the upload check does, through the layout) loads no reader.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.scene.formats.registry import load_function
from bayesian_fields_core.scene.types import Frame


@dataclass(frozen=True)
class CameraFormat:
    """One camera format: where it lies in a scene folder, how it is recognised and read.

    name: the format's id ('transforms', 'colmap', 'inria'): `SceneLayout.camera_kind`,
        `find_cameras`' kind and the upload report's `camera_format`.
    title: what people call it, for the docs' table.
    locations: where in a scene folder it is looked for, in order (the table's rows are tried
        in table order, each row's locations in this order; the first present wins).
    reader: ``module:function`` of the reader: `(path) -> frames`, or `(path, images_dir) ->
        frames` when `images_folder`.
    file_names: exact file names a path named in a scene.yaml is this format by ('cameras.json').
    suffixes: name endings a named file is this format by, when no row's `file_names` took it.
    model_files: a folder is this format when it holds one of these files (COLMAP's images.bin
        or images.txt); empty: the format is one file.
    model_name: what such a folder is called in messages ('COLMAP model').
    images_folder: its frames name images in an images folder the layout resolves (default
        `images/`), not paths relative to the camera file (transforms.json's `file_path`).
    rescale_intrinsics: the stored camera size may differ from the images by 3DGS's resize
        rules (`inria_output.rescale_to_images`).
    applied_transform: its poses may carry nerfstudio's `applied_transform` (undone for the
        world frame; a nerfstudio dataparser transform is relative to it).
    images: ``module:function`` of `(folder, camera_path, *, allow_source_path) -> (images_dir,
        image_root)`, where a capture folder's images are when the format has its own rule
        (cameras.json: `images/` beside it, else what 3DGS's cfg_args names); None: the reader's
        default.
    trainer: the trainer whose output this camera file is (cameras.json: INRIA 3DGS), the
        layout's name when nothing more specific names one; None: any trainer.
    notes: what the reader does beyond decoding, for the docs' table.
    """

    name: str
    title: str
    locations: tuple[str, ...]
    reader: str
    file_names: tuple[str, ...] = ()
    suffixes: tuple[str, ...] = ()
    model_files: tuple[str, ...] = ()
    model_name: str = ""
    images_folder: bool = False
    rescale_intrinsics: bool = False
    applied_transform: bool = False
    images: str | None = None
    trainer: str | None = None
    notes: str = ""

    @property
    def folder(self) -> bool:
        """The format is a folder (a COLMAP model), not one file."""
        return bool(self.model_files)

    def present(self, path: Path) -> bool:
        """`path` holds this format: the file exists, or the folder holds a model file."""
        if self.folder:
            return any((path / name).is_file() for name in self.model_files)
        return path.is_file()

    @property
    def where(self) -> str:
        """Its locations as messages list them ('sparse/0/, sparse/ or ... with a COLMAP model')."""
        names = [f"{loc}/" if self.folder else loc for loc in self.locations]
        listed = names[0] if len(names) == 1 else f"{', '.join(names[:-1])} or {names[-1]}"
        return f"{listed} with a {self.model_name}" if self.folder else listed

    def resolve_images(
        self, folder: Path, camera_path: Path, *, allow_source_path: bool
    ) -> tuple[Path | None, Path | None]:
        """(images_dir, image_root) of a capture folder by the row's `images` rule."""
        if self.images is None:
            return None, None
        found: tuple[Path | None, Path | None] = load_function(self.images)(
            folder, camera_path, allow_source_path=allow_source_path
        )
        return found

    def frames_file(self, path: Path) -> Path:
        """The file that lists the frames of `path`: itself, or a folder's model file that holds
        them (COLMAP's images.bin / images.txt), the one a user edits to drop frames."""
        if not self.folder:
            return path
        return next((path / name for name in self.model_files if (path / name).is_file()), path)

    def read(self, path: Path, images_dir: Path | None) -> list[Frame]:
        """The frames of the camera file (or model folder) `path`; `images_dir`: where image
        names resolve for a format that reads an images folder (None: the reader's default)."""
        reader = load_function(self.reader)
        return reader(path, images_dir) if self.images_folder else reader(path)


SCENE_MODULE = "bayesian_fields_core.scene"

CAMERA_FORMATS: tuple[CameraFormat, ...] = (
    CameraFormat(
        "transforms",
        "nerfstudio / Instant-NGP / Blender `transforms.json`",
        locations=("transforms.json",),
        reader=f"{SCENE_MODULE}.nerfstudio:read_transforms",
        suffixes=(".json",),
        applied_transform=True,
        notes="image paths relative to the file; `applied_transform` and `applied_scale` taken into "
        "account as nerfstudio's dataparser does",
    ),
    CameraFormat(
        "colmap",
        "COLMAP model (binary or text)",
        locations=("sparse/0", "sparse", "colmap/sparse/0"),
        reader=f"{SCENE_MODULE}.colmap:read_colmap",
        model_files=("images.bin", "images.txt"),
        model_name="COLMAP model",
        images_folder=True,
        notes="`colmap/sparse/0` is where ns-process-data leaves it; SIMPLE_RADIAL, RADIAL and "
        "OPENCV images are undistorted on load, fisheye models refused",
    ),
    CameraFormat(
        "inria",
        "INRIA 3DGS `cameras.json`",
        locations=("cameras.json",),
        reader=f"{SCENE_MODULE}.inria:read_cameras_json",
        file_names=("cameras.json",),
        images_folder=True,
        rescale_intrinsics=True,
        images=f"{SCENE_MODULE}.inria_output:inria_images",
        trainer="inria",
        notes="3DGS's output; intrinsics follow images resized by 3DGS's rules; no principal point "
        "or distortion",
    ),
)
"""Table order is the search order in a scene folder: a capture's own file (exact intrinsics)
before `cameras.json`, because a 3DGS output folder copied next to its dataset carries both."""


def camera_format_named(name: str) -> CameraFormat:
    """The row called `name`; KeyError naming the known ones otherwise."""
    for fmt in CAMERA_FORMATS:
        if fmt.name == name:
            return fmt
    raise KeyError(f"unknown camera format {name!r}; known: {', '.join(f.name for f in CAMERA_FORMATS)}")


def camera_locations() -> tuple[str, ...]:
    """Every place in a scene folder cameras are looked for, in search order."""
    return tuple(loc for fmt in CAMERA_FORMATS for loc in fmt.locations)


def find_in_folder(folder: Path) -> tuple[CameraFormat, Path]:
    """The first camera file (or model folder) present in `folder`, in table order."""
    for fmt in CAMERA_FORMATS:
        for location in fmt.locations:
            if fmt.present(folder / location):
                return fmt, folder / location
    raise InputError(
        f"no cameras found ({', '.join(fmt.where for fmt in CAMERA_FORMATS)}, or scene.yaml)",
        source=str(folder),
    )


def detect(path: Path) -> CameraFormat:
    """The format of a camera path named in a scene.yaml: a folder by its model files, a file by
    its exact name, then by its suffix."""
    if path.is_dir():
        folders = [fmt for fmt in CAMERA_FORMATS if fmt.folder]
        found = next((fmt for fmt in folders if fmt.present(path)), None)
        if found is None:
            wanted = " or ".join(f"{f.model_name} ({' / '.join(f.model_files)})" for f in folders)
            raise InputError(f"camera folder has no {wanted}", source=str(path))
        return found
    found = next((fmt for fmt in CAMERA_FORMATS if path.name in fmt.file_names), None)
    found = found or next((fmt for fmt in CAMERA_FORMATS if path.suffix in fmt.suffixes), None)
    if found is None:
        by_files = sorted(CAMERA_FORMATS, key=lambda fmt: fmt.folder)  # files first, then folders
        kinds = [f"a {fmt.model_name} folder" if fmt.folder else f"a {fmt.locations[0]}" for fmt in by_files]
        raise InputError(f"cameras must be {', '.join(kinds[:-1])} or {kinds[-1]}", source=str(path))
    return found


def markdown_table() -> str:
    """The docs' camera table, one row per format in search order (`docs/_build/hooks.py`)."""
    lines = ["| cameras | looked for at | images | notes |", "|---|---|---|---|"]
    for fmt in CAMERA_FORMATS:
        cells = (
            f"{fmt.title} (`{fmt.name}`)",
            ", ".join(f"`{loc}/`" if fmt.folder else f"`{loc}`" for loc in fmt.locations),
            "an images folder (default `images/`)" if fmt.images_folder else "paths in the file",
            fmt.notes,
        )
        lines.append("| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |")
    return "\n".join(lines) + "\n"
