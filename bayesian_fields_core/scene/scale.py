"""The scene scale, and every length the pipeline uses expressed as a multiple of it.

COLMAP's units are arbitrary: the same capture may come back 2.5 or 100 times larger, and
nerfstudio, gsplat and scene.yaml may all rescale it. An absolute length (a depth tolerance of
5 cm, a near plane of 1 cm) then means a different thing in every run, and the answers change
silently. So the pipeline derives one length from the inputs and writes every other length as a
fraction of it.

Definition (`derive_scene_scale`): the median over frames of the median camera-space depth of the
Gaussian centres in view (in front of the camera and projecting inside its image). Why this one:
- it is the distance at which the cameras see the scene, which is what a depth error of a
  rendered splat (the visibility tolerance) grows with, and what near planes must stay below;
- it needs no rendering (one projection of the centres per frame), so it is cheap and the same
  on every backend, the CLI and the workers;
- medians ignore floaters, background Gaussians far behind the scene and frames that look past
  it; it follows a similarity of the whole scene exactly (depths scale, "in view" is invariant);
- it does not depend on which frames a job selects (`frame_stride`, `max_frames`): all frames of
  the scene are used (at most `MAX_SCALE_FRAMES`, spread evenly), and at most
  `MAX_SCALE_GAUSSIANS` centres (an even stride, the same ones in any frame).

A user may set the scale (`PipelineParams.scene_scale`), or any single length in absolute units
(`depth_tolerance`, `edge_padding`); `SceneLengths` records which.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.params import PipelineParams

MAX_SCALE_FRAMES = 64
"""Frames the scale is measured from; more change a median of medians by little."""
MAX_SCALE_GAUSSIANS = 200_000
"""Centres projected per frame (an even stride over the splat); ~1 ms a frame per 100k."""

RENDER_NEAR_FRACTION = 0.005
"""Renderer near plane / scene scale: Gaussians nearer than this to a camera are culled. The
renderer's former fixed 0.01 is 0.0054 of the bundled sample's scale (1.849)."""
VISIBILITY_NEAR_FRACTION = 5e-4
"""Visibility test's near plane / scene scale (was a fixed 1e-3: 0.00054 of the sample's scale)."""
BOX_MIN_SIDE_FRACTION = 5e-4
"""Thinnest side of a reported oriented box / scene scale (was a fixed 1e-3, "1 mm")."""

SCALE_DEFINITION = "median over frames of the median camera-space depth of the Gaussian centres in view"

ScaleSource = Literal["derived", "parameter"]


def _evenly(count: int, limit: int) -> np.ndarray:
    """Indices of at most `limit` of `count` items, spread evenly, first one included."""
    if count <= limit:
        return np.arange(count)
    return np.unique(np.linspace(0, count - 1, limit).round().astype(np.int64))


def frame_median_depth(means: np.ndarray, frame: Any) -> float | None:
    """Median camera depth of the centres `means` (M, 3) inside `frame`'s view, None if none."""
    w2c = np.asarray(frame.world_to_camera, dtype=np.float64)
    cam = means @ w2c[:3, :3].T + w2c[:3, 3]
    z = cam[:, 2]
    front = z > 0
    if not front.any():
        return None
    cam, z = cam[front], z[front]
    K = np.asarray(frame.K, dtype=np.float64)
    u = K[0, 0] * cam[:, 0] / z + K[0, 1] * cam[:, 1] / z + K[0, 2]
    v = K[1, 1] * cam[:, 1] / z + K[1, 2]
    inside = (u >= 0) & (u < frame.width) & (v >= 0) & (v < frame.height)
    return float(np.median(z[inside])) if inside.any() else None


def derive_scene_scale(means: np.ndarray, frames: Sequence[Any]) -> float:
    """The scene scale (module docstring) of Gaussian centres `means` (N, 3) seen by `frames`.

    Raises InputError when no frame sees any Gaussian: such a scene has no scale, and the
    alignment check would refuse it anyway."""
    means = np.asarray(means)
    if means.ndim != 2 or means.shape[1] != 3:
        raise InputError(f"expected (N, 3) Gaussian centres, got {means.shape}", source="scene scale")
    sample = means[_evenly(len(means), MAX_SCALE_GAUSSIANS)].astype(np.float64)
    depths = [frame_median_depth(sample, frames[i]) for i in _evenly(len(frames), MAX_SCALE_FRAMES)]
    seen = [d for d in depths if d is not None and np.isfinite(d) and d > 0]
    if not seen:
        raise InputError(
            "no camera sees any Gaussian, so the scene has no scale; check that the splat and the "
            "cameras are in one frame (or set the scene_scale parameter)",
            source="scene scale",
        )
    return float(np.median(seen))


@dataclass(frozen=True)
class SceneLengths:
    """Every length one run uses, in scene (capture) units, resolved once from the parameters and
    the scene scale. `scale_source`: 'derived' (from the inputs) or 'parameter' (the user's
    `scene_scale`); a length whose absolute override is set is taken as given."""

    scale: float
    scale_source: ScaleSource
    depth_tolerance: float
    edge_padding: float
    render_near: float
    visibility_near: float
    box_min_side: float

    def record(self) -> dict[str, Any]:
        """The JSON-able description written to a run's report and its summary.json."""
        return {
            "value": self.scale,
            "source": self.scale_source,
            "definition": SCALE_DEFINITION,
            "lengths": {
                "depth_tolerance": self.depth_tolerance,
                "edge_padding": self.edge_padding,
                "render_near": self.render_near,
                "visibility_near": self.visibility_near,
                "box_min_side": self.box_min_side,
            },
        }


def scene_units(scene: Any) -> str:
    """How reports name a length of `scene`: 'm' only when the capture is declared metric
    (`Scene.metric`), else 'scene units' (COLMAP's and most trainers' units are arbitrary)."""
    return "m" if getattr(scene, "metric", False) else "scene units"


def scene_lengths(params: PipelineParams, measure: Callable[[], float]) -> SceneLengths:
    """The lengths of a run: each relative default times the scale, unless overridden.

    The one place the length parameters (`params.length_parameters()`) are read: everything
    else reads the `SceneLengths` this returns (a test refuses `params.<length>` elsewhere), so a
    length can never be taken raw on one path and resolved on another. `measure` returns the
    scene's measured scale (`Scene.scale`, `derive_scene_scale`); it is called only when
    `params.scene_scale` is not set, so a run with a given scale never measures one."""
    if params.scene_scale is not None:
        scale, source = float(params.scene_scale), "parameter"
    else:
        scale, source = float(measure()), "derived"
    return SceneLengths(
        scale=scale,
        scale_source=source,  # type: ignore[arg-type]
        depth_tolerance=(
            params.depth_tolerance_scene * scale if params.depth_tolerance is None else params.depth_tolerance
        ),
        edge_padding=params.edge_padding_scene * scale
        if params.edge_padding is None
        else params.edge_padding,
        render_near=RENDER_NEAR_FRACTION * scale,
        visibility_near=VISIBILITY_NEAR_FRACTION * scale,
        box_min_side=BOX_MIN_SIDE_FRACTION * scale,
    )
