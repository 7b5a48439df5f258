"""Which files of a scene folder are the splat, the cameras and the images, and how they line up.

One decision per folder, made here so the loader, the upload validation and the client agree. The
preference order is documented in `scene/loader.py`.

Strategy for frames (why the Gaussians move, not the cameras): when a trainer stored the splat in
a frame of its own (nerfstudio dataparser, gsplat normalisation), we map the Gaussians into the
cameras' (capture) frame with `Similarity.gaussians` (positions, quaternions, log-scales, SH bands)
rather than moving the cameras into the splat frame. Input depth maps come with the cameras and
need no rescaling, and every length the pipeline uses is a fraction of the scene scale measured in
that frame (`scene/scale.py`), so a run on a transformed splat is the run on the untransformed
scene, whatever trainer made it and whatever units the capture has. Results (boxes, centroids) are
reported in the user's splat frame (mapped back with the inverse), in the capture frame, and in
the data's own world frame when a transforms.json's `applied_transform` moved the cameras
(`capture_to_world`).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.scene.camera_formats import camera_format_named, camera_locations, find_in_folder
from bayesian_fields_core.scene.camera_formats import detect as detect_camera_format
from bayesian_fields_core.scene.files import resolve_inside
from bayesian_fields_core.scene.formats.checkpoint import CKPT
from bayesian_fields_core.scene.formats.common import CONVERTED_SPLAT
from bayesian_fields_core.scene.formats.registry import accepted_names, is_splat_candidate
from bayesian_fields_core.scene.formats.sniff import point_cloud_properties
from bayesian_fields_core.scene.inria_output import is_inria_output
from bayesian_fields_core.scene.point_cloud import point_cloud_message
from bayesian_fields_core.scene.scene_yaml import SCENE_YAML, SceneSpecFile, read_scene_yaml
from bayesian_fields_core.scene.similarity import Similarity
from bayesian_fields_core.scene.trainer_runs import GSPLAT_CFG, NERFSTUDIO_CFG, gsplat_run, nerfstudio_run
from bayesian_fields_core.scene.trainer_transforms import (
    DATAPARSER_TRANSFORMS,
    SPLAT_TRANSFORM,
    nerfstudio_to_transforms_frame,
    read_transform_file,
)
from bayesian_fields_core.scene.trainers import layout_row, run_config_names

SPLAT_NAMES = (CONVERTED_SPLAT, "splat.ply")
CAMERA_SOURCES = camera_locations()
"""Where cameras are looked for, in order (`camera_formats.CAMERA_FORMATS`)."""
INRIA_SFM_POINTS = "input.ply"
"""3DGS copies the SfM points here: never a splat in a 3DGS output folder."""
_ITERATION = re.compile(r"iteration_(\d+)$")
_GSPLAT_PLY = re.compile(r"point_cloud_(\d+)\.ply$")


@dataclass
class SceneLayout:
    """Where a scene's parts are.

    trainer: a row of `trainers.TRAINER_LAYOUTS` ('inria', 'nerfstudio', 'gsplat', 'scene.yaml',
    'matrix' (a generic transform file) or 'plain'). camera_kind: a row of
    `camera_formats.CAMERA_FORMATS` ('transforms', 'colmap' or 'inria'). images_dir: where image names
    resolve for COLMAP / cameras.json (None: the reader's default). image_root: the folder those
    names must stay inside. splat_to_capture: the similarity applied to the Gaussians (None: the
    splat is already in the cameras' frame). rescale_intrinsics: cameras.json sizes may differ
    from the images by 3DGS's rules (`inria_output.rescale_to_images`).
    """

    root: Path
    trainer: str
    splat: Path
    camera_kind: str
    camera_path: Path
    images_dir: Path | None = None
    image_root: Path | None = None
    depth_dir: Path | None = None
    depth_scale: float = 1.0
    splat_to_capture: Similarity | None = None
    transform_source: Path | None = None
    rescale_intrinsics: bool = False
    capture_to_world: Similarity | None = None
    metric: bool = False
    """The cameras' units are metres (declared by scene.yaml's `metric`; never guessed)."""
    """The cameras' frame -> the data's own world (COLMAP's): the inverse of a transforms.json's
    `applied_transform` (nerfstudio's ns-process-data writes poses as `applied @ world`); None
    when the camera file is in that world already (COLMAP, cameras.json, no field)."""


def _max_numbered(paths: list[tuple[int, Path]]) -> Path | None:
    return max(paths)[1] if paths else None


def _inria_iteration(folder: Path) -> Path | None:
    return _max_numbered(
        [
            (int(m.group(1)), d / "point_cloud.ply")
            for d in (folder / "point_cloud").glob("iteration_*")
            if (m := _ITERATION.match(d.name)) and (d / "point_cloud.ply").is_file()
        ]
    )


def _gsplat_ply(folder: Path) -> Path | None:
    return _max_numbered(
        [
            (int(m.group(1)), p)
            for p in (folder / "ply").glob("point_cloud_*.ply")
            if (m := _GSPLAT_PLY.match(p.name))
        ]
    )


def _gsplat_ckpt(folder: Path) -> tuple[int, Path] | None:
    """(step, path) of the latest gsplat checkpoint `ckpts/ckpt_<step>[_rank<r>].pt`, rank 0."""
    found = [
        (int(m.group(1)), p)
        for p in (folder / "ckpts").glob("ckpt_*.pt")
        if (m := CKPT.match(p.name)) and (m.group(2) in (None, "0"))
    ]
    return max(found) if found else None


def find_splat_file(folder: Path) -> tuple[Path, str]:
    """(splat, trainer guess) by the loader's preference order; InputError when none or ambiguous.

    A PLY of plain points (`scene.point_cloud`: COLMAP's points3D, an SfM or lidar cloud, often
    named point_cloud.ply) is never taken: a trained splat beside it is, and a folder with
    nothing else is refused with what the file is and how to get a splat."""
    if not folder.is_dir():
        raise InputError("scene folder does not exist", source=str(folder))
    clouds: dict[Path, set[str]] = {}
    for name in SPLAT_NAMES:
        if (folder / name).is_file():
            if (names := point_cloud_properties(folder / name)) is None:
                return folder / name, "plain"
            clouds[folder / name] = names
    if (splat := _inria_iteration(folder)) is not None:
        return splat, "inria"
    ckpt = _gsplat_ckpt(folder)
    if (splat := _gsplat_ply(folder)) is not None:
        step = int(m.group(1)) if (m := _GSPLAT_PLY.match(splat.name)) else 0
        if ckpt is None or ckpt[0] <= step:
            return splat, "gsplat"
    if ckpt is not None:
        return ckpt[1], "gsplat"
    inria = is_inria_output(folder)
    plys = []
    for p in sorted(folder.iterdir()):
        if not is_splat_candidate(p) or (inria and p.name == INRIA_SFM_POINTS):
            continue
        names = clouds.get(p) or point_cloud_properties(p)
        if names is None:
            plys.append(p)
        else:
            clouds[p] = names
    if len(plys) == 1:
        return plys[0], "plain"
    if len(plys) > 1:
        raise InputError(
            f"several splat files and none named {' or '.join(SPLAT_NAMES)}: {', '.join(p.name for p in plys)}"
            " (name the splat in a scene.yaml)",
            source=str(folder),
        )
    if clouds:
        cloud, names = next(iter(clouds.items()))
        raise InputError(point_cloud_message(names), source=str(cloud))
    extra = (
        " (input.ply is 3DGS's SfM point cloud, not a splat)"
        if inria and (folder / INRIA_SFM_POINTS).is_file()
        else ""
    )
    raise InputError(
        "no splat found (point_cloud.ply, splat.ply, point_cloud/iteration_<N>/point_cloud.ply, "
        f"ply/point_cloud_<step>.ply, ckpts/ckpt_<step>.pt, a single splat file ({accepted_names()}), "
        f"or scene.yaml){extra}",
        source=str(folder),
    )


def find_camera_file(folder: Path) -> tuple[str, Path]:
    """(kind, path) of the cameras: the first location of `CAMERA_FORMATS` present, in table
    order (transforms.json, then sparse/0, sparse, colmap/sparse/0 (COLMAP), cameras.json)."""
    fmt, path = find_in_folder(folder)
    return fmt.name, path


def camera_kind_of(path: Path) -> str:
    """The reader for a camera path named in a scene.yaml (`camera_formats.detect`)."""
    return detect_camera_format(path).name


def _capture_transform(transform_file: Path, camera_kind: str, camera_path: Path) -> tuple[Similarity, str]:
    """Splat -> cameras' frame from a transform file, for the camera file actually read."""
    to_original, kind = read_transform_file(transform_file)
    if kind == "nerfstudio" and camera_format_named(camera_kind).applied_transform:
        applied, applied_scale = nerfstudio_to_transforms_frame(camera_path)
        pre = Similarity(applied_scale, np.eye(3), np.zeros(3))
        return pre.then(to_original).then(applied), kind
    return to_original, kind


def _default_transform_file(folder: Path, splat: Path) -> Path | None:
    for candidate in (
        splat.parent / DATAPARSER_TRANSFORMS,
        folder / DATAPARSER_TRANSFORMS,
        folder / SPLAT_TRANSFORM,
    ):
        if candidate.is_file():
            return candidate
    return None


def _from_scene_yaml(folder: Path, spec: SceneSpecFile, source: str) -> SceneLayout:
    splat = resolve_inside(folder, spec.splat, what="splat", source=source)
    if not splat.is_file():
        raise InputError(f"splat {spec.splat!r} does not exist", source=source)
    cameras = resolve_inside(folder, spec.cameras, what="cameras", source=source)
    if not cameras.exists():
        raise InputError(f"cameras {spec.cameras!r} do not exist", source=source)
    fmt = detect_camera_format(cameras)
    kind = fmt.name
    images_dir = None
    if spec.images is not None:
        if not fmt.images_folder:
            raise InputError(
                f"images: not used with a {fmt.locations[0]} (its file_path entries are relative to its "
                "folder); remove it",
                source=source,
            )
        images_dir = resolve_inside(folder, spec.images, what="images folder", source=source)
    elif fmt.images_folder:
        images_dir = resolve_inside(folder, "images", what="images folder", source=source)
    depth_dir = resolve_inside(folder, spec.depth, what="depth folder", source=source) if spec.depth else None
    layout = SceneLayout(
        root=folder,
        trainer="scene.yaml",
        splat=splat,
        camera_kind=kind,
        camera_path=cameras,
        images_dir=images_dir,
        image_root=folder,
        depth_dir=depth_dir,
        depth_scale=spec.depth_scale,
        rescale_intrinsics=fmt.rescale_intrinsics,
        metric=spec.metric,
    )
    if spec.splat_to_camera is not None:
        layout.splat_to_capture = Similarity.from_matrix(
            spec.splat_to_camera, source=f"{source} splat_to_camera"
        )
        layout.transform_source = folder / SCENE_YAML
    elif spec.transform_file is not None:
        path = resolve_inside(folder, spec.transform_file, what="transform file", source=source)
        layout.splat_to_capture, _ = _capture_transform(path, kind, cameras)
        layout.transform_source = path
    return layout


def _nerfstudio_export(run: Path) -> Path:
    """The splat `ns-export gaussian-splat` wrote for a run: in the run folder, else the only
    one under its exports/ (any depth)."""
    try:
        return find_splat_file(run)[0]
    except InputError:
        pass
    found = (
        sorted(p for p in (run / "exports").rglob("*") if is_splat_candidate(p))
        if (run / "exports").is_dir()
        else []
    )
    if len(found) == 1:
        return found[0]
    raise InputError(
        "no exported splat in the nerfstudio run (or several under exports/); run "
        f"`ns-export gaussian-splat --load-config {run / NERFSTUDIO_CFG} --output-dir {run / 'exports'}`",
        source=str(run),
    )


def scene_yaml_layout(folder: Path, *, allow_source_path: bool) -> SceneLayout:
    """The layout a folder's scene.yaml declares (`trainers` row 'scene.yaml'); it never leaves
    the folder, whatever `allow_source_path` says."""
    spec_path = folder / SCENE_YAML
    return _from_scene_yaml(folder, read_scene_yaml(spec_path), str(spec_path))


def gsplat_layout(folder: Path, *, allow_source_path: bool) -> SceneLayout:
    """The layout of a gsplat result_dir (cfg.yml; `trainers` row 'gsplat', `scene.trainer_runs`)."""
    info = gsplat_run(folder, allow_outside=allow_source_path)
    splat, _ = find_splat_file(folder)
    return SceneLayout(
        root=folder,
        trainer="gsplat",
        splat=splat,
        camera_kind="colmap",
        camera_path=info["sparse"],
        images_dir=info["images"],
        image_root=info["images"].parent,
        splat_to_capture=info["splat_to_world"],
        transform_source=folder / GSPLAT_CFG if info["splat_to_world"] is not None else None,
        rescale_intrinsics=info["rescale"],
    )


def nerfstudio_layout(folder: Path, *, allow_source_path: bool) -> SceneLayout:
    """The layout of a nerfstudio run folder (config.yml with dataparser_transforms.json;
    `trainers` row 'nerfstudio', `scene.trainer_runs`)."""
    info = nerfstudio_run(folder, allow_outside=allow_source_path)
    layout = SceneLayout(
        root=folder,
        trainer="nerfstudio",
        splat=_nerfstudio_export(folder),
        camera_kind=info["camera_kind"],
        camera_path=info["camera_path"],
    )
    if camera_format_named(info["camera_kind"]).images_folder:
        layout.images_dir, layout.image_root = info["data"] / "images", info["data"]
    transform = folder / DATAPARSER_TRANSFORMS
    layout.splat_to_capture, _ = _capture_transform(transform, layout.camera_kind, layout.camera_path)
    layout.transform_source = transform
    return layout


def capture_layout(folder: Path, *, allow_source_path: bool) -> SceneLayout:
    """Any other folder (`trainers` row 'plain'): the splat rules, the camera table, then a
    transform file if one lies there. A camera format that is a trainer's output names the
    layout (cameras.json: 'inria') and resolves its images its own way."""
    splat, trainer = find_splat_file(folder)
    fmt, camera_path = find_in_folder(folder)
    layout = SceneLayout(
        root=folder, trainer=trainer, splat=splat, camera_kind=fmt.name, camera_path=camera_path
    )
    if fmt.trainer is not None:
        layout.trainer = fmt.trainer
    layout.rescale_intrinsics = fmt.rescale_intrinsics
    if fmt.images is not None:
        layout.images_dir, layout.image_root = fmt.resolve_images(
            folder, camera_path, allow_source_path=allow_source_path
        )
    transform_file = _default_transform_file(folder, splat)
    if transform_file is not None:
        layout.splat_to_capture, layout.trainer = _capture_transform(transform_file, fmt.name, camera_path)
        layout.transform_source = transform_file
    return layout


def resolve_layout(
    folder: str | Path,
    *,
    allow_source_path: bool = False,
    splat_transform: str | Path | Similarity | None = None,
) -> SceneLayout:
    """The layout of a scene folder (see the loader's docstring for the order of the rules).

    `splat_transform`: a transform file (any format of `read_transform_file`) or a `Similarity`
    splat -> cameras' frame; it overrides what the folder holds. An identity transform is
    dropped (no "capture frame" copy of the results then).
    """
    folder = Path(folder)
    if folder.is_file() and folder.name in run_config_names():
        folder = folder.parent  # `bfields run .../config.yml`: the run folder
    if not folder.is_dir():
        raise InputError("scene folder does not exist", source=str(folder))
    layout: SceneLayout = layout_row(folder).resolver()(folder, allow_source_path=allow_source_path)
    if isinstance(splat_transform, Similarity):
        layout.splat_to_capture, layout.transform_source = splat_transform, None
    elif splat_transform is not None:
        path = Path(splat_transform)
        layout.splat_to_capture, layout.trainer = _capture_transform(
            path, layout.camera_kind, layout.camera_path
        )
        layout.transform_source = path
    if layout.splat_to_capture is not None and layout.splat_to_capture.is_identity:
        layout.splat_to_capture = None
    layout.capture_to_world = _capture_to_world(layout)
    return layout


def _capture_to_world(layout: SceneLayout) -> Similarity | None:
    """Undo a transforms.json's `applied_transform` (results are reported in the data's world
    too); None when there is none to undo."""
    if not camera_format_named(layout.camera_kind).applied_transform:
        return None
    applied, _ = nerfstudio_to_transforms_frame(layout.camera_path)
    return None if applied.is_identity else applied.inverse()
