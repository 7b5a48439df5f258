"""Posed pinhole cameras for synthetic captures: look-at poses on an orbit around the table.

Poses follow the project convention (OpenCV camera axes, world z up), so the same frames can be
written as COLMAP text and as nerfstudio transforms and read back identically.
"""

from __future__ import annotations

import numpy as np

from bayesian_fields_core.eval.synthetic.pieces import SyntheticScene
from bayesian_fields_core.eval.synthetic.spec import SceneSpec
from bayesian_fields_core.geometry.transforms import look_at, pinhole
from bayesian_fields_core.scene.types import Frame


def orbit_frames(
    spec: SceneSpec, target: np.ndarray, rng: np.random.Generator, prefix: str = "frame"
) -> list[Frame]:
    """spec.n_frames cameras evenly spaced in azimuth (capture order), cycling through the heights.

    Positions and the look-at point get a little seeded jitter so no two views are symmetric.
    """
    n = spec.n_frames
    azimuth = 2 * np.pi * np.arange(n) / n + rng.uniform(-0.1, 0.1, n)
    heights = np.asarray(spec.orbit_heights)[np.arange(n) % len(spec.orbit_heights)]
    eyes = np.stack(
        [spec.orbit_radius * np.cos(azimuth), spec.orbit_radius * np.sin(azimuth), heights], axis=1
    )
    eyes += rng.uniform(-spec.orbit_jitter, spec.orbit_jitter, (n, 3))
    targets = target + rng.uniform(-0.05, 0.05, (n, 3)) * np.array([1.0, 1.0, 0.5])
    K = pinhole(spec.width, spec.height, spec.fov_deg)
    return [
        Frame(
            name=f"{prefix}_{i:05d}.png",
            K=K.copy(),
            world_to_camera=look_at(eyes[i], targets[i]),
            width=spec.width,
            height=spec.height,
        )
        for i in range(n)
    ]


def capture_frames(spec: SceneSpec, scene: SyntheticScene, prefix: str = "frame") -> list[Frame]:
    """The scene's cameras: the orbit (default) or a handheld walk, then the border cuts, then
    the outlier dial's views (`outliers.py`).

    Each draws from its own seeded stream ([seed, 1] as before for the path, [seed, 4] for the
    cuts, [seed, 5] for the outliers), so a default spec's cameras are the same as before the
    capture effects existed.
    """
    from bayesian_fields_core.eval.synthetic import capture, outliers  # noqa: PLC0415

    rng = np.random.default_rng([spec.seed, 1])
    if spec.trajectory == "walk":
        frames = capture.walk_frames(spec, scene, rng, prefix)
    else:
        frames = orbit_frames(spec, scene.table_top_center, rng, prefix)
    capture.cut_at_border(frames, spec, scene, np.random.default_rng([spec.seed, 4]))
    outliers.apply_outliers(frames, outliers.outlier_views(spec, scene, len(frames)))
    return frames
