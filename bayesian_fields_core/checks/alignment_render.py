"""The rendered part of the alignment check: do renders of the splat look like the photos?

`alignment_frames` frames spread over the capture (first to last) are rendered with the
project's renderer at a reduced size (longest side `alignment_max_side`, intrinsics scaled with
the image) and compared with their photos, area-downsampled to the same size.

Score: per frame, the zero-mean normalised cross-correlation (ZNCC) of the band-passed grey
render and grey photo (difference of Gaussians, BAND_SIGMAS pixels), weighted by the rendered
alpha; the check's score is the median over the frames. Why this score:
- ZNCC ignores exposure, white balance and contrast differences between a trained splat and
  its photos (gain and offset cancel), which a plain colour difference would punish;
- the band-pass keeps edges and texture at a scale of a few pixels: plain grey correlates too
  well by layout alone (floor below, walls above: photos of the other side of the room score
  0.75 on the sample, a splat scaled 0.5 about 0.5), while the lower cut-off at 1.5 px keeps
  it tolerant to blur and a pixel or two of pose error in a real capture;
- weighting by alpha compares only the pixels the splat claims, so the background colour of
  an object capture (white photo, black render) does not decide the score, and an empty render
  scores 0 (no weight, no evidence);
- it costs a few low-resolution renders (the renderer's time is mostly per Gaussian, so the
  size matters little): about 0.5 s per frame for the sample on one CPU core.
The median of a few frames ignores one bad photo (motion blur, a person walking through).
`coverage` (mean rendered alpha) and `mismatched_frames` (renders correlating well with another
checked photo, and better than with their own: the images belong to other cameras) are reported to
name the cause. Only when the score fails, the frames are rendered again with flipped cameras
(OpenGL <-> OpenCV), to tell a convention mix-up apart from a missing transform.

Threshold (`alignment_min_score` = 0.35), measured on `samples/tabletop` (medians over the 4
frames at 160 px; `bench/bench_alignment.py` prints the table): as shipped 0.99; photos degraded
like an imperfect splat against its capture (blur sigma 3 px, a 2 px shift, noise, gamma and
gain) 0.75, and still 0.46 with blur 4 px and a 4 px shift; misaligned: scaled 0.5 + shifted
0.4 m 0.01, scaled 0.5 0.01, shifted 0.4 m 0.15, rotated 20 degrees 0.17, photos of other
cameras 0.25, shifted 10 m 0 (nothing rendered in view). 0.35 sits above every misaligned copy
and below the heavily degraded good one. (Flipped cameras are caught by the geometric part.)
"""

from __future__ import annotations

import time

import numpy as np
from PIL import Image
from scipy import ndimage

from bayesian_fields_core.checks.alignment_reports import FrameScore, RenderReport, spread_indices
from bayesian_fields_core.errors import InputError
from bayesian_fields_core.geometry.transforms import OPENGL_TO_OPENCV
from bayesian_fields_core.params import PipelineParams
from bayesian_fields_core.render import GaussianRenderer
from bayesian_fields_core.scene.images import load_image
from bayesian_fields_core.scene.scale import scene_lengths
from bayesian_fields_core.scene.types import Frame, Scene

BAND_SIGMAS = (1.5, 4.5)
"""The band-pass kept before correlating: grey blurred by the first sigma minus grey blurred by
the second (pixels at the reduced size), a difference of Gaussians."""
GREY = np.array([0.299, 0.587, 0.114], dtype=np.float32)
"""Rec. 601 luma weights."""
MIN_WEIGHT = 1e-3
"""A render with less total alpha than this share of its pixels carries no evidence: score 0."""


def reduced_camera(frame: Frame, max_side: int) -> tuple[np.ndarray, int, int]:
    """(K, width, height) of the frame shrunk so its longest side is at most max_side.

    Continuous pixel coordinates scale with the image (pixel i covers [i, i+1)), so fx, cx are
    multiplied by the width ratio and fy, cy by the height ratio.
    """
    s = min(1.0, max_side / max(frame.width, frame.height))
    width, height = max(1, round(frame.width * s)), max(1, round(frame.height * s))
    scale = np.diag([width / frame.width, height / frame.height, 1.0])
    return scale @ np.asarray(frame.K, dtype=np.float64), width, height


def band_pass(rgb: np.ndarray) -> np.ndarray:
    """(H, W) float32 difference-of-Gaussians of the luma of an (H, W, 3) image in [0, 1]."""
    grey = rgb.astype(np.float32) @ GREY
    fine, coarse = (ndimage.gaussian_filter(grey, s) for s in BAND_SIGMAS)
    return fine - coarse


def weighted_zncc(a: np.ndarray, b: np.ndarray, weights: np.ndarray) -> float:
    """ZNCC in [-1, 1] of two (H, W) images under (H, W) non-negative weights; 0 when either
    image is flat or the weights are (nearly) empty."""
    w = weights.astype(np.float64).ravel()
    total = w.sum()
    if total < MIN_WEIGHT * w.size:
        return 0.0
    a = a.astype(np.float64).ravel()
    b = b.astype(np.float64).ravel()
    da = a - (w @ a) / total
    db = b - (w @ b) / total
    var = (w @ (da * da)) * (w @ (db * db))
    if var <= 1e-12 * total * total:
        return 0.0
    return float((w @ (da * db)) / np.sqrt(var))


def _photo(frame: Frame, width: int, height: int) -> np.ndarray:
    """(H, W) band-passed luma of the frame's photo, area-downsampled to width x height."""
    rgb = load_image(frame)
    if (width, height) != (frame.width, frame.height):
        rgb = np.asarray(Image.fromarray(rgb).resize((width, height), Image.Resampling.BOX))
    return band_pass(rgb.astype(np.float32) / 255.0)


def _render(
    renderer: GaussianRenderer, frame: Frame, max_side: int, *, flip: bool
) -> tuple[np.ndarray, np.ndarray]:
    """((H, W) band-passed luma of the un-premultiplied render, (H, W) blurred alpha)."""
    K, width, height = reduced_camera(frame, max_side)
    w2c = np.asarray(frame.world_to_camera, dtype=np.float64)
    if flip:
        w2c = OPENGL_TO_OPENCV @ w2c
    out = renderer.render(K, w2c, width, height)
    assert out.rgb is not None
    alpha = out.alpha
    rgb = out.rgb / np.maximum(alpha, 1e-3)[..., None]  # background 0: undo the premultiplication
    return band_pass(np.clip(rgb, 0.0, 1.0)), ndimage.gaussian_filter(alpha, BAND_SIGMAS[0])


def _near_plane(scene: Scene, params: PipelineParams) -> float | None:
    """The run's renderer near plane (a fraction of the scene scale), so the check renders what
    the pipeline will; None (the renderer's own) when no camera sees the splat: the scale is
    undefined then and the check's scores say why better than the scale's error would."""
    try:
        return scene_lengths(params, scene.scale).render_near
    except InputError:
        return None


def rendered_alignment(scene: Scene, params: PipelineParams, *, device: str = "cpu") -> RenderReport:
    """Score `params.alignment_frames` frames of the scene (see the module docstring)."""
    t0 = time.perf_counter()
    frames = [scene.frames[i] for i in spread_indices(len(scene.frames), params.alignment_frames)]
    renderer = GaussianRenderer(scene.gaussians, device=device, near_plane=_near_plane(scene, params))
    max_side = params.alignment_max_side
    sizes = [reduced_camera(f, max_side)[1:] for f in frames]
    photos = [_photo(f, w, h) for f, (w, h) in zip(frames, sizes, strict=True)]
    renders = [_render(renderer, f, max_side, flip=False) for f in frames]
    scores = []
    mismatched = 0
    for i, (frame, (grey, alpha)) in enumerate(zip(frames, renders, strict=True)):
        own = weighted_zncc(grey, photos[i], alpha)
        # Other photos of the same size only: a render is compared pixel for pixel.
        others = {
            j: weighted_zncc(grey, photo, alpha)
            for j, photo in enumerate(photos)
            if j != i and photo.shape == grey.shape
        }
        best = max(others, key=lambda j: others[j], default=i)
        # A mismatch needs a good match elsewhere, not the larger of two noise-level scores.
        if best != i and others[best] > max(own, params.alignment_min_score):
            mismatched += 1
        else:
            best = i
        scores.append(
            FrameScore(
                frame=frame.name, score=own, coverage=float(alpha.mean()), best_match=frames[best].name
            )
        )
    score = float(np.median([s.score for s in scores]))
    flipped = None
    if score < params.alignment_min_score:
        flipped_renders = [_render(renderer, f, max_side, flip=True) for f in frames]
        flipped = float(
            np.median([weighted_zncc(g, p, a) for (g, a), p in zip(flipped_renders, photos, strict=True)])
        )
    width, height = sizes[0]
    return RenderReport(
        frames=scores,
        score=score,
        coverage=float(np.median([s.coverage for s in scores])),
        mismatched_frames=mismatched,
        flipped_score=flipped,
        width=width,
        height=height,
        seconds=time.perf_counter() - t0,
    )
