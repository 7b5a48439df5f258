"""Whole-folder validation for uploads: everything a job will read, checked before it is queued.

A job that fails on frame 900 because one JPEG is truncated wastes GPU time; so at upload we read
the full splat (values included: NaNs are caught here) and decode every image and depth map,
checking each against its camera's size. The splat is streamed in chunks (`scene.ply_scan`,
`scene.formats.scan`), so
the memory this takes is bounded whatever the file's size; only a sample of its Gaussians is kept
(for the geometric alignment check and the warnings' extent). Costs one read of the splat (two
when its extent is non-zero) plus one decode per image.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import Any

from bayesian_fields_core.errors import InputError, input_boundary
from bayesian_fields_core.scene.formats import READER_FAILURES, check_splat_header, open_source, read_splat
from bayesian_fields_core.scene.formats.scan import scan_source
from bayesian_fields_core.scene.images import check_image, load_depth
from bayesian_fields_core.scene.loader import frames_of_layout, resolve_layout
from bayesian_fields_core.scene.ply import DEFAULT_MAX_GAUSSIANS, read_ply_header
from bayesian_fields_core.scene.ply_scan import SplatScan, sample_index, scan_ply
from bayesian_fields_core.scene.sanity import splat_warnings
from bayesian_fields_core.scene.types import Scene


def validate_scene_folder(
    folder: str | Path,
    *,
    max_gaussians: int = DEFAULT_MAX_GAUSSIANS,
    max_frames: int | None = None,
    alignment: bool = False,
) -> dict[str, Any]:
    """Validate a scene folder and summarise it; raises InputError on the first problem found.

    Cheap checks come first so a hostile upload costs little: the splat header (counts), the
    camera file (every path inside the folder, every file present) and the frame count against
    `max_frames`, all before the splat body is read or one image is decoded.

    Returns {splat, gaussians, sh_degree, camera_format, camera_file, frames, image_size
    ([w, h] of the most common size), image_sizes (all distinct sizes), distorted_frames,
    depth_frames, layout, splat_to_capture (4x4 or None), warnings (see `scene.sanity`)}; paths
    are relative to the folder. Never follows a 3DGS cfg_args source_path out of the folder (an
    upload reads only itself). With `alignment`, the geometric part of the alignment check (no
    rendering, default thresholds) runs on the splat (in the cameras' frame) and frames, refusing
    a splat that does not line up with its cameras; its shares land in `alignment`.
    """
    folder = Path(folder)
    with input_boundary(str(folder), what="cannot validate the scene"):
        return _validate(folder, max_gaussians, max_frames, alignment)


def _validate(folder: Path, max_gaussians: int, max_frames: int | None, alignment: bool) -> dict[str, Any]:
    layout = resolve_layout(folder, allow_source_path=False)
    splat, kind, camera_path = layout.splat, layout.camera_kind, layout.camera_path
    splat_format = check_splat_header(splat, max_gaussians=max_gaussians)
    frames = frames_of_layout(layout)
    if max_frames is not None and len(frames) > max_frames:
        raise InputError(f"{len(frames)} frames; at most {max_frames} are allowed", source=str(camera_path))
    scan = _scan_splat(splat, splat_format, max_gaussians)
    for frame in frames:
        check_image(frame)
        load_depth(frame)
    sizes = Counter((f.width, f.height) for f in frames)
    extra: dict[str, Any] = {}
    if alignment:
        from bayesian_fields_core.checks.alignment import check_alignment
        from bayesian_fields_core.params import PipelineParams

        sample = scan.sample  # the Gaussians the geometric check would sample from the whole splat
        captured = sample if layout.splat_to_capture is None else layout.splat_to_capture.gaussians(sample)
        report = check_alignment(Scene(captured, frames, root=folder), PipelineParams(), rendered=False)
        if report is not None:
            extra["alignment"] = {
                "frustum_share": round(report.geometry.frustum_share, 4),
                "extent_ratio": report.geometry.extent_ratio,
            }
    return {
        "splat": splat.relative_to(folder).as_posix(),
        "gaussians": scan.count,
        "sh_degree": scan.sh_degree,
        "splat_format": splat_format,
        "camera_format": kind,
        "camera_file": camera_path.relative_to(folder).as_posix(),
        "frames": len(frames),
        "image_size": list(sizes.most_common(1)[0][0]),
        "image_sizes": sorted(list(s) for s in sizes),
        "distorted_frames": sum(1 for f in frames if f.distortion),
        "depth_frames": sum(1 for f in frames if f.depth_path is not None),
        "layout": layout.trainer,
        "splat_to_capture": None
        if layout.splat_to_capture is None
        else layout.splat_to_capture.matrix.tolist(),
        **extra,
        "warnings": scan.warnings,
    }


def _scan_splat(splat: Path, splat_format: str, max_gaussians: int) -> SplatScan:
    """The splat's count, SH degree, fixed-seed sample and warnings, in bounded memory whatever
    the format or what its header declares: an INRIA-layout PLY is streamed by `scene.ply_scan`;
    every other format is opened by row range (compressed payloads inflated through bounded
    reads into an unlinked temporary file beside the upload) and walked by `formats.scan`."""
    from bayesian_fields_core.checks.alignment import GEOMETRY_MAX_GAUSSIANS

    if splat_format == "ply":
        names = {name for name, _ in read_ply_header(splat, max_gaussians=max_gaussians).properties}
        if "f_dc_0" in names:
            return scan_ply(splat, sample_size=GEOMETRY_MAX_GAUSSIANS, max_gaussians=max_gaussians)
    if splat_format == "checkpoint":  # CLI only (an upload refuses .pt by name): read whole
        gaussians = read_splat(splat, max_gaussians=max_gaussians)
        sample = gaussians.subset(sample_index(len(gaussians), GEOMETRY_MAX_GAUSSIANS))
        return SplatScan(len(gaussians), gaussians.sh_degree, sample, splat_warnings(gaussians))
    spill_dir = splat if splat.is_dir() else splat.parent
    with input_boundary(str(splat), what=f"cannot read the {splat_format} splat", extra=READER_FAILURES):
        with open_source(splat, splat_format, max_gaussians=max_gaussians, spill_dir=spill_dir) as source:
            return scan_source(source, sample_size=GEOMETRY_MAX_GAUSSIANS)
