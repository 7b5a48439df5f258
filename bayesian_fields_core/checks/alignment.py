"""Does the splat line up with its cameras? A check run before perception spends any time.

A splat exported in a trainer's internal frame (nerfstudio's `dataparser_transforms.json` not
applied, gsplat's `normalize_world_space` similarity not undone), a camera file whose OpenGL
matrices were read as OpenCV ones, or an images folder from another capture all load fine and
run to a confident but meaningless answer table. Two parts catch them:

Geometric (cheap, no rendering; the API runs it at upload). On a fixed-seed sample of at most
GEOMETRY_MAX_GAUSSIANS Gaussians and GEOMETRY_MAX_FRAMES frames spread over the capture:
- `frustum_share`: opacity-weighted share of the Gaussians in front of and inside at least one
  camera's image. A trained splat's unseen Gaussians end up nearly transparent (3DGS resets every
  opacity during training and only Gaussians some view sees climb back), so a real, aligned splat
  scores close to 1; a splat lying beside or behind the cameras scores near 0.
- `flipped_frustum_share`: the same with every camera's y and z axes flipped (OpenGL <-> OpenCV);
  when that one passes and the given one does not, the camera convention is the likely cause.
- `extent_ratio`: the splat's robust extent (diagonal of its 2nd-98th percentile box) over the
  camera baseline (diagonal of the cameras' centre box); far from 1 in either direction means a
  unit or normalisation scale was dropped (None with a single camera position).

Rendered (`alignment_render.py`; the CLI and the worker run it): a few frames are rendered at a
reduced resolution and compared with their photos. The verdict and its one-line cause are built
here so every caller (CLI, API, worker) refuses with the same words.
"""

from __future__ import annotations

import hashlib
import time
from functools import cache
from pathlib import Path

import numpy as np

from bayesian_fields_core.checks.alignment_reports import (
    AlignmentReport,
    FrameShares,
    GeometryReport,
    RenderReport,
    spread_indices,
)
from bayesian_fields_core.errors import InputError
from bayesian_fields_core.geometry.transforms import OPENGL_TO_OPENCV
from bayesian_fields_core.params import PipelineParams
from bayesian_fields_core.scene.types import Frame, Scene

GEOMETRY_MAX_GAUSSIANS = 50_000
"""Gaussians sampled for the geometric part (a share estimated to about +-0.5 % at this size)."""
GEOMETRY_MAX_FRAMES = 200
"""Frames used by the geometric part, spread over the capture (union shares saturate quickly)."""
EXTENT_PERCENTILES = (2.0, 98.0)
"""The splat's extent ignores the few far floaters a trainer leaves behind."""
_PACKAGE = Path(__file__).resolve().parents[1]
CODE_FILES = (
    "checks/alignment.py",
    "checks/alignment_render.py",
    "checks/alignment_reports.py",
    "scene/images.py",
    "scene/scale.py",
    "render/",
)
"""The source a report follows from (the check, the renderer, the image loader, the scene scale):
a cached verdict is reused only with the code that made it (`job/alignment_cache.py`)."""
OVERRIDE = "set alignment_check=false to skip the check (CLI: --param alignment_check=false)"


@cache
def code_fingerprint() -> str:
    """SHA-256 (32 hex digits) of the bytes of `CODE_FILES` (a folder: its .py files, sorted)."""
    h = hashlib.sha256()
    for name in CODE_FILES:
        path = _PACKAGE / name
        for file in sorted(path.rglob("*.py")) if path.is_dir() else [path]:
            h.update(file.relative_to(_PACKAGE).as_posix().encode() + b"\0" + file.read_bytes())
    return h.hexdigest()[:32]


def _sample(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """(M, 3) float64 means and (M,) opacity weights of a fixed-seed sample of the Gaussians."""
    g = scene.gaussians
    n = len(g)
    index = np.arange(n)
    if n > GEOMETRY_MAX_GAUSSIANS:
        index = np.sort(np.random.default_rng(0).choice(n, GEOMETRY_MAX_GAUSSIANS, replace=False))
    means = np.asarray(g.means[index], dtype=np.float64)
    weights = np.asarray(g.opacities[index], dtype=np.float64)
    finite = np.all(np.isfinite(means), axis=1) & np.isfinite(weights)
    return means[finite], weights[finite]


def _inside(means: np.ndarray, frame: Frame, w2c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(in front, in front and inside the image) boolean masks of (M, 3) world points."""
    cam = means @ w2c[:3, :3].T + w2c[:3, 3]
    z = cam[:, 2]
    front = z > 0
    safe = np.where(front, z, 1.0)
    u = frame.K[0, 0] * cam[:, 0] / safe + frame.K[0, 2]
    v = frame.K[1, 1] * cam[:, 1] / safe + frame.K[1, 2]
    inside = front & (u >= 0) & (u < frame.width) & (v >= 0) & (v < frame.height)
    return front, inside


def geometric_alignment(scene: Scene) -> GeometryReport:
    """The geometric part (see the module docstring); costs about a millisecond per frame."""
    if not scene.frames:
        raise InputError("the scene has no frames", source="cameras")
    means, weights = _sample(scene)
    total = float(weights.sum())
    if len(means) == 0 or total <= 0:
        raise InputError("the splat has no finite, visible Gaussian", source="splat")
    frames = [scene.frames[i] for i in spread_indices(len(scene.frames), GEOMETRY_MAX_FRAMES)]
    seen = np.zeros(len(means), dtype=bool)
    seen_flipped = np.zeros(len(means), dtype=bool)
    shares = []
    for frame in frames:
        w2c = np.asarray(frame.world_to_camera, dtype=np.float64)
        front, inside = _inside(means, frame, w2c)
        seen |= inside
        seen_flipped |= _inside(means, frame, OPENGL_TO_OPENCV @ w2c)[1]
        shares.append(
            FrameShares(
                frame=frame.name,
                in_front=float(weights[front].sum() / total),
                in_frustum=float(weights[inside].sum() / total),
            )
        )
    lo, hi = np.percentile(means, EXTENT_PERCENTILES, axis=0)
    extent = float(np.linalg.norm(hi - lo))
    centres = np.stack([np.asarray(f.camera_centre, dtype=np.float64) for f in scene.frames])
    baseline = float(np.linalg.norm(centres.max(axis=0) - centres.min(axis=0)))
    ratio = extent / baseline if baseline > 1e-9 * max(1.0, extent) and extent > 0 else None
    return GeometryReport(
        gaussians_sampled=len(means),
        frames_checked=len(frames),
        in_front_share=float(np.mean([s.in_front for s in shares])),
        frustum_share=float(weights[seen].sum() / total),
        flipped_frustum_share=float(weights[seen_flipped].sum() / total),
        splat_extent=extent,
        camera_baseline=baseline,
        extent_ratio=ratio,
        frames=shares,
    )


_TRANSFORM_HINT = (
    "a splat-to-camera transform was likely not applied (nerfstudio dataparser_transforms.json, "
    "gsplat normalize_world_space)"
)
_CONVENTION_HINT = (
    "the camera file likely mixes the OpenGL (y up, z back) and OpenCV (y down, z forward) conventions"
)


def geometry_cause(geo: GeometryReport, params: PipelineParams) -> str | None:
    """The one-line refusal of the geometric part, or None when it passes."""
    if geo.frustum_share < params.alignment_min_frustum_share:
        seen = (
            f"only {100 * geo.frustum_share:.0f}% of the splat lies in front of and inside the camera "
            f"frustums (alignment_min_frustum_share {100 * params.alignment_min_frustum_share:.0f}%)"
        )
        if geo.flipped_frustum_share >= max(params.alignment_min_frustum_share, geo.frustum_share + 0.1):
            why = f"{_CONVENTION_HINT}: with y/z flipped {100 * geo.flipped_frustum_share:.0f}% would be"
        else:
            why = _TRANSFORM_HINT
        return f"{seen}; {why}; {OVERRIDE}"
    r = params.alignment_max_extent_ratio
    if geo.extent_ratio is not None and not 1.0 / r <= geo.extent_ratio <= r:
        return (
            f"the splat spans {geo.extent_ratio:.3g}x the camera baseline (allowed 1/{r:g} to {r:g}, "
            f"alignment_max_extent_ratio): a unit or normalisation scale was likely dropped "
            f"(nerfstudio dataparser_transforms.json scale, gsplat normalize_world_space); {OVERRIDE}"
        )
    return None


def render_cause(rendered: RenderReport, params: PipelineParams) -> str | None:
    """The one-line refusal of the rendered part, or None when it passes."""
    if rendered.score >= params.alignment_min_score:
        return None
    seen = (
        f"renders of the splat do not match the photos (score {rendered.score:.2f} < "
        f"alignment_min_score {params.alignment_min_score:g} over {len(rendered.frames)} frames)"
    )
    if rendered.flipped_score is not None and rendered.flipped_score >= params.alignment_min_score:
        why = f"{_CONVENTION_HINT}: with y/z flipped the score is {rendered.flipped_score:.2f}"
    elif len(rendered.frames) >= 3 and rendered.mismatched_frames * 2 > len(rendered.frames):
        why = (
            f"{rendered.mismatched_frames} of {len(rendered.frames)} renders match another camera's photo "
            "better than their own: wrong images folder or image order"
        )
    else:
        why = f"{_TRANSFORM_HINT}, or the images folder is not this capture's"
    return f"{seen}; {why}; {OVERRIDE} or lower alignment_min_score"


def assess_alignment(
    scene: Scene, params: PipelineParams, *, rendered: bool = True, device: str = "cpu"
) -> AlignmentReport:
    """Run the geometric part, then (when `rendered` and geometry passed) the rendered part."""
    t0 = time.perf_counter()
    geo = geometric_alignment(scene)
    cause = geometry_cause(geo, params)
    report = None
    if rendered and cause is None:
        from bayesian_fields_core.checks.alignment_render import rendered_alignment

        report = rendered_alignment(scene, params, device=device)
        cause = render_cause(report, params)
    return AlignmentReport(
        passed=cause is None, cause=cause, geometry=geo, rendered=report, seconds=time.perf_counter() - t0
    )


def check_alignment(
    scene: Scene, params: PipelineParams, *, rendered: bool = True, device: str = "cpu"
) -> AlignmentReport | None:
    """`assess_alignment`, raising `InputError` (one line: cause + override) when it fails.

    Returns None without looking when `params.alignment_check` is false."""
    if not params.alignment_check:
        return None
    return assess_alignment(scene, params, rendered=rendered, device=device).raise_if_failed()
