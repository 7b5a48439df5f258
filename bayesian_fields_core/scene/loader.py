"""Find and load a scene folder: one splat `.ply` plus one camera file, with their images.

Splat, first match wins:
  1. `point_cloud.ply`, 2. `splat.ply` (at the top of the folder),
  3. the only `*.ply` at the top (several -> error listing them),
  4. `point_cloud/iteration_<N>/point_cloud.ply` with the largest N (a 3DGS training output).
Cameras, first match wins:
  1. `transforms.json` (nerfstudio / Instant-NGP / Blender),
  2. `sparse/0/` then `sparse/` (COLMAP, binary or text),
  3. `cameras.json` (INRIA 3DGS output).
The capture formats come before `cameras.json` because a 3DGS output folder copied next to its
dataset carries both, and `cameras.json` may hold a downscaled training resolution.
Images are resolved against `images/` (COLMAP, cameras.json) or the transforms.json folder.
"""

from __future__ import annotations

import re
from pathlib import Path

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.scene.colmap import read_colmap
from bayesian_fields_core.scene.files import require_files
from bayesian_fields_core.scene.inria import read_cameras_json
from bayesian_fields_core.scene.nerfstudio import read_transforms
from bayesian_fields_core.scene.ply import DEFAULT_MAX_GAUSSIANS, read_ply
from bayesian_fields_core.scene.types import Frame, Scene

SPLAT_NAMES = ("point_cloud.ply", "splat.ply")
CAMERA_SOURCES = ("transforms.json", "sparse/0", "sparse", "cameras.json")
_ITERATION = re.compile(r"iteration_(\d+)$")


def find_splat(folder: str | Path) -> Path:
    """The splat file of a scene folder, by the preference order in the module docstring."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError("scene folder does not exist", source=str(folder))
    for name in SPLAT_NAMES:
        if (folder / name).is_file():
            return folder / name
    plys = sorted(p for p in folder.glob("*.ply") if p.is_file())
    if len(plys) == 1:
        return plys[0]
    if len(plys) > 1:
        raise InputError(
            f"several .ply files and none named {' or '.join(SPLAT_NAMES)}: {', '.join(p.name for p in plys)}",
            source=str(folder),
        )
    iterations = [
        (int(m.group(1)), d / "point_cloud.ply")
        for d in (folder / "point_cloud").glob("iteration_*")
        if (m := _ITERATION.match(d.name)) and (d / "point_cloud.ply").is_file()
    ]
    if iterations:
        return max(iterations)[1]
    raise InputError(
        "no splat found (point_cloud.ply, splat.ply, a single *.ply, or "
        "point_cloud/iteration_<N>/point_cloud.ply)",
        source=str(folder),
    )


def find_cameras(folder: str | Path) -> tuple[str, Path]:
    """(kind, path) of the camera file: kind is 'transforms', 'colmap' or 'inria'."""
    folder = Path(folder)
    for source in CAMERA_SOURCES:
        path = folder / source
        if source.endswith(".json"):
            if path.is_file():
                return ("transforms" if source == "transforms.json" else "inria"), path
        elif any((path / f"images{ext}").is_file() for ext in (".bin", ".txt")):
            return "colmap", path
    raise InputError(
        "no cameras found (transforms.json, sparse/0/ or sparse/ with a COLMAP model, or cameras.json)",
        source=str(folder),
    )


def load_frames(folder: str | Path) -> tuple[str, Path, list[Frame]]:
    """(kind, camera path, frames) of a scene folder, after checking every referenced file exists."""
    folder = Path(folder)
    kind, path = find_cameras(folder)
    if kind == "transforms":
        frames = read_transforms(path)
    elif kind == "colmap":
        frames = read_colmap(path, folder / "images")
    else:
        frames = read_cameras_json(path, folder / "images")
    require_files((f.image_path for f in frames), what="image files", source=str(path))
    require_files(
        (f.depth_path for f in frames if f.depth_path is not None), what="depth files", source=str(path)
    )
    return kind, path, frames


def load_scene(folder: str | Path, *, max_gaussians: int = DEFAULT_MAX_GAUSSIANS) -> Scene:
    """Load the splat and the frames (in capture order) of a scene folder."""
    folder = Path(folder)
    splat = find_splat(folder)
    _, _, frames = load_frames(folder)
    return Scene(gaussians=read_ply(splat, max_gaussians=max_gaussians), frames=frames, root=folder)
