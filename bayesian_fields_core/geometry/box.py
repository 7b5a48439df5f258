"""The oriented box type: a centre, a rotation whose columns are the box axes, full extents.

Kept apart from `obb` (which finds the minimum box of a point set with scipy and numba) so that
reading a result's boxes needs only numpy: the light result reader (`results.reader`) imports it.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from bayesian_fields_core.errors import InputError


@dataclass(frozen=True)
class OrientedBox:
    """A box: `center` (3,), `rotation` (3, 3) whose columns are the box axes (a proper rotation),
    `extents` (3,) full side lengths along those axes."""

    center: np.ndarray
    rotation: np.ndarray
    extents: np.ndarray

    def __post_init__(self) -> None:
        center = np.asarray(self.center, dtype=np.float64).reshape(-1)
        rotation = np.asarray(self.rotation, dtype=np.float64)
        extents = np.asarray(self.extents, dtype=np.float64).reshape(-1)
        if center.shape != (3,) or rotation.shape != (3, 3) or extents.shape != (3,):
            raise InputError(
                f"oriented box: expected center (3,), rotation (3,3), extents (3,); got "
                f"{center.shape}, {rotation.shape}, {extents.shape}"
            )
        if not (np.isfinite(center).all() and np.isfinite(rotation).all() and np.isfinite(extents).all()):
            raise InputError("oriented box: non-finite center, rotation or extents")
        if (extents < 0).any():
            raise InputError(f"oriented box: negative extents {extents.tolist()}")
        if not np.allclose(rotation.T @ rotation, np.eye(3), atol=1e-6):
            raise InputError("oriented box: rotation is not orthonormal")
        object.__setattr__(self, "center", center)
        object.__setattr__(self, "rotation", rotation)
        object.__setattr__(self, "extents", extents)

    @property
    def volume(self) -> float:
        return float(np.prod(self.extents))

    @property
    def half_extents(self) -> np.ndarray:
        return self.extents / 2.0

    def to_local(self, points: np.ndarray) -> np.ndarray:
        """Coordinates of world points along the box axes, relative to the centre."""
        return (np.asarray(points, dtype=np.float64) - self.center) @ self.rotation

    def corners(self) -> np.ndarray:
        """The 8 corners (8, 3), in binary order of the sign pattern (-,-,-), (-,-,+), ..."""
        signs = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1], indexing="ij")).reshape(3, -1).T
        return self.center + (signs * self.half_extents) @ self.rotation.T

    def contains(self, points: np.ndarray, tol: float = 1e-9) -> np.ndarray | bool:
        """Whether each point lies inside the box, `tol` (absolute) allowed beyond each face.

        A single point (3,) gives a bool, a set (n, 3) a boolean array.
        """
        pts = np.asarray(points, dtype=np.float64)
        inside = (np.abs(self.to_local(pts.reshape(-1, 3))) <= self.half_extents + tol).all(axis=1)
        return bool(inside[0]) if pts.ndim == 1 else inside

    def to_dict(self) -> dict[str, list]:
        return {
            "center": self.center.tolist(),
            "rotation": self.rotation.tolist(),
            "extents": self.extents.tolist(),
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> OrientedBox:
        try:
            return cls(data["center"], data["rotation"], data["extents"])
        except KeyError as exc:
            raise InputError(f"oriented box: missing field {exc.args[0]!r}") from None
        except (TypeError, ValueError) as exc:
            if isinstance(exc, InputError):
                raise
            raise InputError(f"oriented box: malformed field ({exc})") from None
