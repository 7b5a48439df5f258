"""Find and load a scene folder: one splat `.ply` plus one camera file, with their images.

Layout, first match wins (`scene/layout.py` decides, so loader, upload validation and client agree):
  0. `scene.yaml` in the folder names the splat, cameras, images, optional depth and an optional
     splat-to-camera similarity (`scene/scene_yaml.py`); nothing else is guessed then.
Trainer run folders (`scene/trainer_runs.py`): a gsplat result_dir (`cfg.yml`) or a nerfstudio
run (`config.yml` + `dataparser_transforms.json`) names its data; the rules below are then used
for the splat only. Any format of `scene/formats/` is a splat.
Splat:
  1. `point_cloud.ply`, 2. `splat.ply` (at the top of the folder; `splat.ply` is what
     `ns-export gaussian-splat` writes),
  3. `point_cloud/iteration_<N>/point_cloud.ply` with the largest N (an INRIA 3DGS output folder),
  4. `ply/point_cloud_<step>.ply` with the largest step (a gsplat `simple_trainer` result folder),
     or `ckpts/ckpt_<step>_rank0.pt` when its step is later,
  5. the only splat file at the top (any name a row of `scene/formats/registry.py` matches)
     (several -> error listing them). In a 3DGS output folder
     (cameras.json with cfg_args or point_cloud/), `input.ply` (the SfM points) never counts.
Trainer layouts are the rows of `scene/trainers.py` (scene.yaml, gsplat, nerfstudio, then the
capture folder rules below), tried in table order.
Cameras, the rows of `scene/camera_formats.py` in table order:
  1. `transforms.json` (nerfstudio / Instant-NGP / Blender),
  2. `sparse/0/`, `sparse/`, then `colmap/sparse/0/` (COLMAP, binary or text),
  3. `cameras.json` (INRIA 3DGS output). Its images: `images/` beside it, else the `images`
     folder named by `cfg_args` inside the scene folder, else (only with `allow_source_path`,
     which the CLI sets and the service never does) that folder under cfg_args' `source_path`.
     Intrinsics follow the images when their size is 3DGS's resize of the camera size
     (`scene/inria_output.py`).
Frame transform (splat -> cameras), first found: the `splat_transform` argument (CLI
`--splat-transform`), scene.yaml's, `dataparser_transforms.json` beside the splat or at the top
(nerfstudio), `splat_transform.json` at the top (`{"camera_to_splat": 4x4}` from gsplat's
normalisation, or `{"splat_to_camera": 4x4}`). The Gaussians are mapped into the cameras' frame;
`Scene.splat_to_capture` keeps the similarity so results can be reported in both frames.
World frame: a transforms.json's `applied_transform` (ns-process-data's COLMAP -> nerfstudio
rotation) is undone for reporting only: `Scene.capture_to_world` is its inverse, and results give
centroids and boxes in that frame too (the data's own world, i.e. COLMAP's).
The capture formats come before `cameras.json` because a 3DGS output folder copied next to its
dataset carries both, and the capture's own file has exact intrinsics.
"""

from __future__ import annotations

from pathlib import Path

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.scene.camera_formats import camera_format_named
from bayesian_fields_core.scene.files import require_files, resolve_inside
from bayesian_fields_core.scene.formats import read_splat
from bayesian_fields_core.scene.inria_output import rescale_to_images
from bayesian_fields_core.scene.layout import (
    CAMERA_SOURCES,
    SPLAT_NAMES,
    SceneLayout,
    find_camera_file,
    find_splat_file,
    resolve_layout,
)
from bayesian_fields_core.scene.ply import DEFAULT_MAX_GAUSSIANS
from bayesian_fields_core.scene.similarity import Similarity
from bayesian_fields_core.scene.types import Frame, Scene

DEPTH_EXTENSIONS = (".png", ".tif", ".tiff", ".npy")
"""Tried in order for a scene.yaml depth folder: `<depth>/<image path without extension><ext>`."""

__all__ = [
    "CAMERA_SOURCES",
    "SPLAT_NAMES",
    "find_cameras",
    "find_splat",
    "load_frames",
    "load_scene",
    "resolve_layout",
]


def find_splat(folder: str | Path) -> Path:
    """The splat file of a scene folder, by the preference order in the module docstring."""
    folder = Path(folder)
    if (folder / "scene.yaml").is_file():
        return resolve_layout(folder).splat
    return find_splat_file(folder)[0]


def find_cameras(folder: str | Path) -> tuple[str, Path]:
    """(kind, path) of the camera file: kind is a `camera_formats.CAMERA_FORMATS` row's name
    ('transforms', 'colmap' or 'inria')."""
    folder = Path(folder)
    if (folder / "scene.yaml").is_file():
        layout = resolve_layout(folder)
        return layout.camera_kind, layout.camera_path
    return find_camera_file(folder)


def _attach_depth(frames: list[Frame], layout: SceneLayout) -> list[Frame]:
    """Depth paths from a scene.yaml depth folder, each resolved inside the scene folder."""
    assert layout.depth_dir is not None
    source = str(layout.root / "scene.yaml")
    rel = layout.depth_dir.relative_to(layout.root.resolve()).as_posix()
    missing = []
    for frame in frames:
        stem = Path(frame.name).with_suffix("").as_posix()
        found = None
        for ext in DEPTH_EXTENSIONS:
            candidate = resolve_inside(layout.root, f"{rel}/{stem}{ext}", what="depth", source=source)
            if candidate.is_file():
                found = candidate
                break
        if found is None:
            missing.append(f"{rel}/{stem}.*")
        frame.depth_path = found
        frame.depth_scale = layout.depth_scale
    if missing:
        raise InputError(f"{len(missing)} depth maps are missing: {', '.join(missing[:5])}", source=source)
    return frames


def read_layout_frames(layout: SceneLayout) -> list[Frame]:
    """The frames a layout's camera file describes, as read (no file they name is checked yet)."""
    return camera_format_named(layout.camera_kind).read(layout.camera_path, layout.images_dir)


def frames_file(layout: SceneLayout) -> Path:
    """The file that lists the layout's frames: transforms.json, cameras.json, or the COLMAP
    model's images.bin / images.txt (not the model's folder, which is `camera_path`)."""
    return camera_format_named(layout.camera_kind).frames_file(layout.camera_path)


def shown_path(layout: SceneLayout, path: Path) -> str:
    """`path` relative to the scene folder, as the user sees the folder; whole when outside it
    (a trainer's data folder)."""
    try:
        return path.resolve().relative_to(layout.root.resolve()).as_posix()
    except ValueError:
        return str(path)


def missing_images_fix(layout: SceneLayout) -> str:
    """What to do about frames whose image files are missing, naming the file that lists them."""
    return f"restore those image files, or drop those frames from {shown_path(layout, frames_file(layout))}"


def frames_of_layout(layout: SceneLayout) -> list[Frame]:
    """The frames a layout's camera file describes, checked against the files they reference."""
    path = layout.camera_path
    frames = read_layout_frames(layout)
    require_files(
        (f.image_path for f in frames), what="image files", source=str(path), fix=missing_images_fix(layout)
    )
    if layout.rescale_intrinsics:
        frames = rescale_to_images(frames, source=str(path))
    if layout.depth_dir is not None:
        frames = _attach_depth(frames, layout)
    require_files(
        (f.depth_path for f in frames if f.depth_path is not None), what="depth files", source=str(path)
    )
    return frames


def load_frames(folder: str | Path, *, allow_source_path: bool = False) -> tuple[str, Path, list[Frame]]:
    """(kind, camera path, frames) of a scene folder, after checking every referenced file exists."""
    layout = resolve_layout(folder, allow_source_path=allow_source_path)
    return layout.camera_kind, layout.camera_path, frames_of_layout(layout)


def load_scene(
    folder: str | Path,
    *,
    max_gaussians: int = DEFAULT_MAX_GAUSSIANS,
    allow_source_path: bool = False,
    splat_transform: str | Path | Similarity | None = None,
) -> Scene:
    """Load the splat and the frames (in capture order) of a scene folder.

    The Gaussians come back in the cameras' frame: when the layout has a splat -> camera
    similarity it is applied here and kept as `Scene.splat_to_capture`.
    `allow_source_path`: follow a 3DGS cfg_args `source_path` outside the folder (CLI only).
    """
    folder = Path(folder)
    layout = resolve_layout(folder, allow_source_path=allow_source_path, splat_transform=splat_transform)
    frames = frames_of_layout(layout)
    gaussians = read_splat(layout.splat, max_gaussians=max_gaussians)
    if layout.splat_to_capture is not None:
        gaussians = layout.splat_to_capture.gaussians(gaussians)
    return Scene(
        gaussians=gaussians,
        frames=frames,
        root=folder,
        splat_path=layout.splat,
        layout=layout.trainer,
        splat_to_capture=layout.splat_to_capture,
        capture_to_world=layout.capture_to_world,
        metric=layout.metric,
    )
