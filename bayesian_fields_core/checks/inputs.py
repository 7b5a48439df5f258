"""Every input a run needs, checked before any expensive work, every problem reported at once.

Why: the readers stop at their first problem, and a run reads its inputs one after another, so a
user met them one run at a time ("no tasks given", fixed, then "no cameras found") and a wrong
image size only after the alignment check had rendered for seconds. Here the cheap checks of
every input run first (the splat's header, the camera file, each image's presence and its size
from its header, nothing decoded or rendered) and each problem is kept, with its fix, so one
`InputErrors` lists them all. The readers still check everything again when the run loads.
"""

from __future__ import annotations

from pathlib import Path

from bayesian_fields_core.errors import InputError, raise_input_errors
from bayesian_fields_core.scene.formats import check_splat_header
from bayesian_fields_core.scene.images import image_size
from bayesian_fields_core.scene.layout import SceneLayout, find_camera_file, find_splat_file
from bayesian_fields_core.scene.loader import (
    frames_file,
    frames_of_layout,
    read_layout_frames,
    resolve_layout,
    shown_path,
)
from bayesian_fields_core.scene.ply import DEFAULT_MAX_GAUSSIANS
from bayesian_fields_core.scene.scene_yaml import SCENE_YAML
from bayesian_fields_core.scene.trainer_runs import GSPLAT_CFG, NERFSTUDIO_CFG
from bayesian_fields_core.scene.types import Frame

SHOWN = 5
"""Frames named in one problem (the rest are counted)."""


def check_run_inputs(
    folder: str | Path,
    *,
    found: list[InputError] | None = None,
    allow_source_path: bool = False,
    splat_transform: str | Path | None = None,
    max_gaussians: int = DEFAULT_MAX_GAUSSIANS,
) -> None:
    """Raise every problem of a run's inputs together: `found` (what the caller met already, such
    as its tasks and parameters) and the scene folder's (`scene_problems`). One problem is raised
    as itself, several as `InputErrors`; nothing when all is well."""
    problems = list(found or [])
    problems += scene_problems(
        Path(folder),
        allow_source_path=allow_source_path,
        splat_transform=splat_transform,
        max_gaussians=max_gaussians,
    )
    raise_input_errors(problems)


def scene_problems(
    folder: Path,
    *,
    allow_source_path: bool = False,
    splat_transform: str | Path | None = None,
    max_gaussians: int = DEFAULT_MAX_GAUSSIANS,
) -> list[InputError]:
    """The problems of a scene folder: splat, cameras, images present, image sizes."""
    try:
        layout = resolve_layout(folder, allow_source_path=allow_source_path, splat_transform=splat_transform)
    except InputError as exc:
        return _layout_problems(folder, exc)
    problems: list[InputError] = []
    try:
        check_splat_header(layout.splat, max_gaussians=max_gaussians)
    except InputError as exc:
        problems.append(exc)
    return problems + _frame_problems(layout)


def _layout_problems(folder: Path, exc: InputError) -> list[InputError]:
    """`resolve_layout` stops at the splat; in a plain folder (no scene.yaml, no trainer run,
    which name both) the cameras are looked for too, so a folder missing both says so once."""
    if not folder.is_dir() or any(
        (folder / name).is_file() for name in (SCENE_YAML, GSPLAT_CFG, NERFSTUDIO_CFG)
    ):
        return [exc]
    problems: list[InputError] = []
    for find in (find_splat_file, find_camera_file):
        try:
            find(folder)
        except InputError as missing:
            problems.append(missing)
    return problems or [exc]


def _frame_problems(layout: SceneLayout) -> list[InputError]:
    """Missing images (with their fix) and images whose size is not their camera's."""
    try:
        frames = read_layout_frames(layout)
    except InputError as exc:
        return [exc]
    problems: list[InputError] = []
    missing = [f for f in frames if f.image_path is None or not Path(f.image_path).is_file()]
    if missing:
        try:
            frames_of_layout(layout)  # the loader's own message for them, and the fix
        except InputError as exc:
            problems.append(exc)
        if layout.rescale_intrinsics:  # 3DGS's camera sizes follow the images: all must be there
            return problems
    else:
        try:
            frames = frames_of_layout(layout)  # rescaled intrinsics, depth maps
        except InputError as exc:
            return [exc]
    absent = {id(f) for f in missing}
    present = [f for f in frames if id(f) not in absent]
    return problems + _size_problems(layout, present)


def _size_problems(layout: SceneLayout, frames: list[Frame]) -> list[InputError]:
    """One problem for every image that cannot be read or is not its camera's size."""
    problems: list[InputError] = []
    wrong: list[tuple[Frame, tuple[int, int]]] = []
    for frame in frames:
        try:
            size = image_size(Path(str(frame.image_path)))
        except InputError as exc:
            problems.append(exc)
            continue
        if size != (frame.width, frame.height):
            wrong.append((frame, size))
    if not wrong:
        return problems
    fix = (
        "give the images at the size their cameras were made for (not a resized copy), or correct "
        f"the image sizes and intrinsics in {shown_path(layout, frames_file(layout))}"
    )
    if len(wrong) == 1:
        frame, (w, h) = wrong[0]
        message = f"image is {w}x{h} but its camera ({frame.name}) is {frame.width}x{frame.height}; {fix}"
        return [*problems, InputError(message, source=str(frame.image_path))]
    listed = ", ".join(f"{f.name} is {w}x{h}, its camera {f.width}x{f.height}" for f, (w, h) in wrong[:SHOWN])
    more = f" and {len(wrong) - SHOWN} more" if len(wrong) > SHOWN else ""
    message = f"{len(wrong)} images are not their cameras' size ({listed}{more}); {fix}"
    return [*problems, InputError(message, source=str(layout.camera_path))]
