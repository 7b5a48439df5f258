"""In-memory scene types: the Gaussians of a splat and the posed frames that observe it.

Everything downstream (renderer, fusion, objects) consumes these plain numpy containers, so
the file formats stay confined to the readers in this package.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np


def sh_coefficient_count(degree: int) -> int:
    """Number of SH coefficients per colour channel for a degree (0..3)."""
    return (degree + 1) ** 2


@dataclass
class Gaussians:
    """A 3D Gaussian splat in the INRIA parameterisation (arrays share the first axis N).

    means: (N, 3) float32 world positions.
    log_scales: (N, 3) float32, log of the per-axis standard deviations.
    quats: (N, 4) float32, rotation quaternions in (w, x, y, z) order, as stored (not normalised).
    opacity_logits: (N,) float32, sigmoid(opacity_logits) is the opacity.
    sh: (N, K, 3) float32 SH coefficients with K = (degree + 1)^2; sh[:, 0, :] is f_dc.
    extra: other per-vertex properties of the source file (e.g. nx, ny, nz), kept for round trips.
    """

    means: np.ndarray
    log_scales: np.ndarray
    quats: np.ndarray
    opacity_logits: np.ndarray
    sh: np.ndarray
    extra: dict[str, np.ndarray] = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.means.shape[0])

    @property
    def sh_degree(self) -> int:
        return int(round(np.sqrt(self.sh.shape[1]))) - 1

    @property
    def opacities(self) -> np.ndarray:
        return 1.0 / (1.0 + np.exp(-self.opacity_logits))

    def subset(self, index: np.ndarray) -> Gaussians:
        """The Gaussians selected by a boolean mask or an index array, all attributes kept."""
        return Gaussians(
            means=self.means[index],
            log_scales=self.log_scales[index],
            quats=self.quats[index],
            opacity_logits=self.opacity_logits[index],
            sh=self.sh[index],
            extra={k: v[index] for k, v in self.extra.items()},
        )


@dataclass
class Frame:
    """One posed image, as a pinhole camera in the OpenCV convention (x right, y down, z forward).

    K: (3, 3) float64 intrinsics. world_to_camera: (4, 4) float64 rigid transform.
    Distorted camera models are undistorted (or refused) by the camera readers, so everything
    downstream can assume a pinhole model.
    """

    name: str
    K: np.ndarray
    world_to_camera: np.ndarray
    width: int
    height: int
    image_path: Path | None = None
    depth_path: Path | None = None
    depth_scale: float = 1.0  # metres per stored depth unit (e.g. 0.001 for millimetre PNGs)
    distortion: dict[str, float] | None = None  # model parameters the image loader must remove

    @property
    def camera_to_world(self) -> np.ndarray:
        return np.linalg.inv(self.world_to_camera)

    @property
    def camera_centre(self) -> np.ndarray:
        return self.camera_to_world[:3, 3]


@dataclass
class Scene:
    """A splat plus its frames in capture order; root is the folder the files came from.

    `gaussians` are in the frames' (capture) frame. `splat_to_capture` (a
    `scene.similarity.Similarity`) is the transform the loader applied to the splat file's
    Gaussians to get there, None when the file was already in that frame; results map boxes and
    centroids back with its inverse. `layout` names the recognised layout ('inria', 'nerfstudio',
    'gsplat', 'scene.yaml', 'matrix' or 'plain').
    """

    gaussians: Gaussians
    frames: list[Frame]
    root: Path | None = None
    splat_path: Path | None = None
    layout: str = "plain"
    splat_to_capture: Any = None
    capture_to_world: Any = None
    """`Similarity` from the cameras' frame to the data's own world (COLMAP's), when the camera
    file is in a frame of its own (nerfstudio's `applied_transform`); None: the same frame."""
    metric: bool = False
    """The cameras' units are known to be metres (scene.yaml `metric: true`)."""
    _scale: float | None = field(default=None, repr=False, compare=False)

    def scale(self) -> float:
        """The scene scale (`scene.scale.derive_scene_scale`), measured once per scene."""
        if self._scale is None:
            from bayesian_fields_core.scene.scale import derive_scene_scale

            self._scale = derive_scene_scale(self.gaussians.means, self.frames)
        return self._scale

    def splat_frame_gaussians(self) -> Gaussians:
        """The Gaussians in the splat file's own frame (what exports are written in)."""
        if self.splat_to_capture is None:
            return self.gaussians
        return self.splat_to_capture.inverse().gaussians(self.gaussians)
