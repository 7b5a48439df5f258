"""Turn uploaded files into a validated scene folder, then copy it into the tenant's bucket prefix.

Both upload paths (one multipart request, or presigned multipart uploads straight to the bucket)
end here with a list of (role, file name, local path). The files are laid out as a scene folder
the core loader understands, checked by `validate_scene_folder` (PLY header and counts, camera
file parses, every image decodes and matches its camera), and only then uploaded under
``scenes/<id>/input/``. Validation happens before the first byte is stored, so a bad upload
never touches data that is already there. It includes the cheap, geometric part of the alignment
check (is the splat in front of and inside the camera frustums?); the form field
``alignment_check=false`` skips it, as the job parameter of the same name skips the rendered part.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Any

from bayesian_fields_core.errors import InputError, input_boundary
from bayesian_fields_core.job.store import Store
from bayesian_fields_core.scene.formats import check_upload_name
from bayesian_fields_core.scene.trainer_transforms import DATAPARSER_TRANSFORMS, SPLAT_TRANSFORM
from bayesian_fields_service.config.settings import ServiceSettings
from bayesian_fields_service.scenes.archives import ArchiveLimits, extract_archive, is_archive_name
from bayesian_fields_service.scenes.layout import input_prefix

#: Camera files by name -> the folder they go to inside the scene (COLMAP's usual layout).
CAMERA_FILES: dict[str, str] = {
    "transforms.json": "",
    "cameras.json": "",
    "cameras.txt": "sparse/0/",
    "images.txt": "sparse/0/",
    "points3D.txt": "sparse/0/",
    "cameras.bin": "sparse/0/",
    "images.bin": "sparse/0/",
    "points3D.bin": "sparse/0/",
    # COLMAP 3.12 writes rigs and frames beside the model; poses come from images.*, these are
    # stored with it and ignored by the reader.
    "frames.txt": "sparse/0/",
    "rigs.txt": "sparse/0/",
    "frames.bin": "sparse/0/",
    "rigs.bin": "sparse/0/",
}
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".webp")
#: Optional splat-to-cameras frame files (nerfstudio's, or the generic/gsplat one), stored at the
#: top of the scene folder where `scene.layout` looks for them.
TRANSFORM_FILES = (DATAPARSER_TRANSFORMS, SPLAT_TRANSFORM)
ROLES = ("splat", "cameras", "images", "transform")


NAME_LIMIT = 200
"""Longest scene name, in characters."""


@dataclass(frozen=True)
class UploadedFile:
    role: str  # one of ROLES
    name: str  # client file name (already reduced to a base name)
    path: Path


def clean_filename(raw: str, *, field_name: str) -> str:
    """The base name of a client-supplied file name; refuses names that are empty or hidden."""
    name = PurePosixPath(raw.replace("\\", "/")).name.strip()
    if not name or name in (".", "..") or name.startswith(".") or any(ord(c) < 32 for c in name):
        raise InputError(f"unusable file name {raw!r}", source=field_name)
    if len(name.encode("utf-8", "surrogatepass")) > 255:  # NAME_MAX counts bytes, not characters
        raise InputError(f"file name longer than 255 bytes: {name[:40]!r}...", source=field_name)
    return name


def checked_name(name: str | None) -> str | None:
    """A scene's optional name as stored: at most `NAME_LIMIT` characters, no control characters
    (a NUL is refused by PostgreSQL's text, and none belongs in a name); InputError otherwise."""
    if not name:
        return None
    if len(name) > NAME_LIMIT or any(ord(c) < 0x20 or ord(c) == 0x7F for c in name):
        raise InputError(f"at most {NAME_LIMIT} characters, and no control characters", source="name")
    return name


def archive_limits(settings: ServiceSettings) -> ArchiveLimits:
    """The deployment's bounds on an image archive (BFIELDS_MAX_ARCHIVE_*)."""
    return ArchiveLimits(
        max_members=settings.max_archive_members, max_bytes=settings.max_archive_uncompressed_bytes
    )


def ingest(
    settings: ServiceSettings,
    store: Store,
    scene_id: str,
    files: Sequence[UploadedFile],
    work: Path,
    *,
    alignment: bool = True,
) -> tuple[int, int, dict[str, Any]]:
    """Assemble and validate the files in `work`, then copy the scene to its ``input/`` in the
    tenant's `store` (blocking: the API runs it in a thread). Returns (files, bytes, summary)."""
    scene_dir = work / "scene"
    assemble_scene(files, scene_dir, archive_limits(settings))
    summary = validate_scene(
        scene_dir, max_gaussians=settings.max_gaussians, max_frames=settings.max_frames, alignment=alignment
    )
    n, size = upload_scene_folder(store, scene_dir, input_prefix(scene_id))
    return n, size, summary


def _one_splat(files: Sequence[UploadedFile]) -> UploadedFile:
    splats = [f for f in files if f.role == "splat"]
    if len(splats) != 1:
        raise InputError(f"expected exactly one splat file, got {len(splats)}", source="splat")
    check_upload_name(splats[0].name)
    return splats[0]


def _camera_files(files: Sequence[UploadedFile]) -> list[UploadedFile]:
    cams = [f for f in files if f.role == "cameras"]
    if not cams:
        raise InputError(
            "no camera file; send transforms.json, cameras.json or COLMAP cameras/images (.txt or .bin)",
            source="cameras",
        )
    for cam in cams:
        if cam.name not in CAMERA_FILES:
            raise InputError(
                f"{cam.name!r} is not a supported camera file; expected one of {', '.join(CAMERA_FILES)}",
                source="cameras",
            )
    return cams


def _transform_file(files: Sequence[UploadedFile]) -> UploadedFile | None:
    transforms = [f for f in files if f.role == "transform"]
    if len(transforms) > 1:
        raise InputError(f"expected at most one transform file, got {len(transforms)}", source="transform")
    if transforms and transforms[0].name not in TRANSFORM_FILES:
        raise InputError(
            f"{transforms[0].name!r} is not a transform file; expected {' or '.join(TRANSFORM_FILES)}",
            source="transform",
        )
    return transforms[0] if transforms else None


def assemble_scene(files: Sequence[UploadedFile], scene_dir: Path, limits: ArchiveLimits) -> None:
    """Lay the uploaded files out as a scene folder (files are moved, archives extracted).

    Any failure to lay a file out (a name the filesystem refuses, ...) is the upload's fault:
    InputError, so a 4xx."""
    with input_boundary("upload", what="cannot lay out the uploaded files"):
        _assemble(files, scene_dir, limits)


def _assemble(files: Sequence[UploadedFile], scene_dir: Path, limits: ArchiveLimits) -> None:
    splat = _one_splat(files)
    cams = _camera_files(files)
    transform = _transform_file(files)
    images = [f for f in files if f.role == "images"]
    unknown = [f for f in files if f.role not in ROLES]
    if unknown:
        raise InputError(f"unexpected form field {unknown[0].role!r}; use {', '.join(ROLES)}", source="form")
    scene_dir.mkdir(parents=True, exist_ok=True)
    splat.path.replace(scene_dir / splat.name)
    if transform is not None:
        transform.path.replace(scene_dir / transform.name)
    for cam in cams:
        dest = scene_dir / CAMERA_FILES[cam.name] / cam.name
        if dest.exists():
            raise InputError(f"camera file {cam.name!r} sent twice", source="cameras")
        dest.parent.mkdir(parents=True, exist_ok=True)
        cam.path.replace(dest)
    image_dir = scene_dir / "images"
    archives = [f for f in images if is_archive_name(f.name)]
    if archives:
        if len(images) != 1:
            raise InputError("send either one image archive or image files, not both", source="images")
        extract_archive(archives[0].path, image_dir, limits, source=archives[0].name)
        return
    if not images:
        raise InputError("no images; send image files or one zip/tar archive as 'images'", source="images")
    image_dir.mkdir(parents=True, exist_ok=True)
    for img in images:
        if not img.name.lower().endswith(IMAGE_SUFFIXES):
            raise InputError(f"{img.name!r} is not an image ({', '.join(IMAGE_SUFFIXES)})", source="images")
        dest = image_dir / img.name
        if dest.exists():
            raise InputError(f"image {img.name!r} sent twice", source="images")
        img.path.replace(dest)


def validate_scene(
    scene_dir: Path, *, max_gaussians: int, max_frames: int, alignment: bool = True
) -> dict[str, Any]:
    """Run the core validator (with the geometric alignment check unless `alignment` is false)
    and the service's size limits; returns the validation summary.

    Messages name files relative to the scene folder, never the API's temp paths (the loaders
    report resolved paths, so the resolved folder is stripped too). The frame limit is checked
    by the validator before any image is decoded."""
    from bayesian_fields_core.checks.upload import validate_scene_folder

    try:
        summary = validate_scene_folder(
            scene_dir, max_gaussians=max_gaussians, max_frames=max_frames, alignment=alignment
        )
    except InputError as exc:
        message = str(exc)
        for folder in {str(scene_dir.resolve()), str(scene_dir)}:
            message = message.replace(f"{folder}/", "").replace(folder, "<scene>")
        raise InputError(message) from None
    gaussians = summary.get("gaussians", summary.get("num_gaussians"))
    if isinstance(gaussians, int) and gaussians > max_gaussians:
        raise InputError(f"{gaussians} Gaussians; at most {max_gaussians} are allowed", source="splat")
    frames = summary.get("frames", summary.get("num_frames"))
    if isinstance(frames, int) and frames > max_frames:
        raise InputError(f"{frames} frames; at most {max_frames} are allowed", source="cameras")
    return summary


def alignment_wanted(value: str | bool | None) -> bool:
    """The upload's `alignment_check` field: absent or true runs the check, false skips it."""
    if value is None or isinstance(value, bool):
        return value is not False
    text = value.strip().lower()
    if text in ("", "true", "1", "yes"):
        return True
    if text in ("false", "0", "no"):
        return False
    raise InputError(f"expected true or false, got {value!r}", source="alignment_check")


def upload_scene_folder(store: Store, scene_dir: Path, prefix: str) -> tuple[int, int]:
    """Copy every file of `scene_dir` under `prefix` (deleting what was written on failure).

    Returns (files, bytes)."""
    paths = sorted(p for p in scene_dir.rglob("*") if p.is_file())
    try:
        for path in paths:
            store.put_file(prefix + path.relative_to(scene_dir).as_posix(), path)
    except BaseException:
        store.delete_prefix(prefix)
        raise
    return len(paths), sum(p.stat().st_size for p in paths)
