"""The pieces a synthetic scene is made of: instances, labels, sampled surfaces, the scene itself.

Plain data shared by the scene builder, the capture effects and the cameras, kept in a module of
their own so those three import it instead of each other.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from bayesian_fields_core.eval.synthetic.spec import SceneSpec
from bayesian_fields_core.scene.types import Gaussians


@dataclass(frozen=True)
class Label:
    """A label patch of `colour` on instance `instance_id`, facing `normal` (world, unit)."""

    instance_id: int
    colour: str
    normal: np.ndarray


@dataclass(frozen=True)
class Instance:
    """One ground-truth instance: an object (possibly compound) or a room structure.

    center/rotation/extents are its oriented box (rotation columns are the box axes, extents are
    full side lengths), fitted to its Gaussians' centres in the instance's own frame.
    """

    id: int
    name: str
    kind: str
    colour: str | None
    category: str  # "object" or "background"
    center: np.ndarray
    rotation: np.ndarray
    extents: np.ndarray
    n_gaussians: int
    label: str | None = None  # colour of its label patch (capture.add_labels), None without one


@dataclass
class SyntheticScene:
    """Gaussians with their per-Gaussian instance ids and the instances' descriptions."""

    spec: SceneSpec
    gaussians: Gaussians
    instance_ids: np.ndarray  # (N,) int32
    instances: list[Instance]
    table_top_center: np.ndarray  # (3,) the point cameras look at
    labels: list[Label] = field(default_factory=list)
    label_gaussians: np.ndarray | None = None  # (N,) bool: the label patches' Gaussians


def yaw_rotation(angle: float) -> np.ndarray:
    """(3, 3) rotation by `angle` radians about the world z axis (objects stand upright)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@dataclass
class Piece:
    """Sampled surface of one instance before it becomes Gaussians."""

    name: str
    kind: str
    colour: str | None
    category: str
    points: np.ndarray
    normals: np.ndarray
    rgb: np.ndarray
    density: float
    frame_rotation: np.ndarray  # the instance frame used for its oriented box
    origin: np.ndarray = field(default_factory=lambda: np.zeros(3))  # its local frame's origin
