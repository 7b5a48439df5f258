"""Similarity transforms (x -> s R x + t) between a splat's frame and its cameras' (capture) frame.

Trainers store the Gaussians in a frame of their own: nerfstudio's dataparser re-orients, centres
and scales the world; gsplat's `normalize_world_space` does the same. To bring a splat back to its
cameras we apply one similarity to the *Gaussians* (the chosen strategy, see `scene/layout.py`):
means -> s R x + t, rotations -> R q (quaternion product), log-scales -> + log s, and the view-
dependent SH bands rotated by R, so a render of the transformed splat from a camera equals the
render of the original splat from that camera moved into the splat frame. Boxes and centroids
map back with the inverse.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.geometry.obb import OrientedBox
from bayesian_fields_core.geometry.transforms import rotation_error, rotmat_to_quat
from bayesian_fields_core.scene.types import Gaussians

SIMILARITY_TOLERANCE = 1e-4
"""Largest deviation (relative to the scale) of a file's 3x3 block from s times a rotation."""


@dataclass(frozen=True)
class Similarity:
    """x -> scale * rotation @ x + translation. rotation (3, 3) proper, scale > 0, translation (3,)."""

    scale: float
    rotation: np.ndarray
    translation: np.ndarray

    @classmethod
    def identity(cls) -> Similarity:
        return cls(1.0, np.eye(3), np.zeros(3))

    @classmethod
    def from_matrix(cls, matrix: Any, *, source: str) -> Similarity:
        """From a (4, 4) or (3, 4) matrix whose 3x3 block is s R; InputError naming `source`."""
        try:
            m = np.asarray(matrix, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise InputError(f"transform is not a numeric matrix ({exc})", source=source) from None
        if m.shape == (3, 4):
            m = np.vstack([m, [0.0, 0.0, 0.0, 1.0]])
        if m.shape != (4, 4) or not np.isfinite(m).all():
            raise InputError(
                f"transform must be a finite 4x4 (or 3x4) matrix, got shape {m.shape}", source=source
            )
        if not np.allclose(m[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9):
            raise InputError(f"transform's last row must be [0, 0, 0, 1], got {m[3].tolist()}", source=source)
        block = m[:3, :3]
        det = float(np.linalg.det(block))
        if det <= 0:
            raise InputError(
                f"transform's 3x3 block has determinant {det:.6g}: a reflection or degenerate, not a similarity",
                source=source,
            )
        scale = det ** (1.0 / 3.0)
        rotation = block / scale
        if float(rotation_error(rotation)) > SIMILARITY_TOLERANCE:
            raise InputError(
                "transform is not a similarity (its 3x3 block is not a uniform scale times a rotation)",
                source=source,
            )
        return cls(scale, _orthonormalise(rotation), m[:3, 3].copy())

    @property
    def matrix(self) -> np.ndarray:
        """(4, 4) float64."""
        out = np.eye(4)
        out[:3, :3] = self.scale * self.rotation
        out[:3, 3] = self.translation
        return out

    @property
    def is_identity(self) -> bool:
        return bool(np.allclose(self.matrix, np.eye(4), atol=1e-12))

    def inverse(self) -> Similarity:
        rt = self.rotation.T
        return Similarity(1.0 / self.scale, rt, -(rt @ self.translation) / self.scale)

    def then(self, other: Similarity) -> Similarity:
        """`other` applied after `self` (other o self)."""
        return Similarity(
            self.scale * other.scale,
            other.rotation @ self.rotation,
            other.scale * (other.rotation @ self.translation) + other.translation,
        )

    def points(self, x: np.ndarray) -> np.ndarray:
        """(..., 3) points mapped, float64."""
        return self.scale * (np.asarray(x, dtype=np.float64) @ self.rotation.T) + self.translation

    def box(self, box: OrientedBox) -> OrientedBox:
        """The image of an oriented box (a similarity maps boxes to boxes: axes rotate, extents scale)."""
        return OrientedBox(self.points(box.center), self.rotation @ box.rotation, box.extents * self.scale)

    def gaussians(self, g: Gaussians) -> Gaussians:
        """The splat mapped: positions, rotations, log-scales and SH bands 1..3; other attributes
        (opacity, colour DC, extra properties) copied. float64 arithmetic, float32 out.

        `extra` normals (nx, ny, nz), when present, are rotated too so a round trip keeps them.
        """
        means = self.points(g.means).astype(np.float32)
        q_r = rotmat_to_quat(self.rotation)
        quats = _quat_multiply(q_r, g.quats.astype(np.float64)).astype(np.float32)
        log_scales = (g.log_scales.astype(np.float64) + np.log(self.scale)).astype(np.float32)
        sh = rotate_sh(g.sh, self.rotation)
        extra = dict(g.extra)
        if all(k in extra for k in ("nx", "ny", "nz")) and all(
            extra[k].dtype.kind == "f" for k in ("nx", "ny", "nz")
        ):
            normals = (
                np.stack([extra["nx"], extra["ny"], extra["nz"]], axis=1).astype(np.float64) @ self.rotation.T
            )
            for i, k in enumerate(("nx", "ny", "nz")):
                extra[k] = normals[:, i].astype(extra[k].dtype)
        return Gaussians(
            means=means,
            log_scales=log_scales,
            quats=quats,
            opacity_logits=g.opacity_logits.copy(),
            sh=sh,
            extra=extra,
        )

    def to_dict(self) -> dict[str, Any]:
        return {"matrix": self.matrix.tolist(), "scale": float(self.scale)}


def _orthonormalise(r: np.ndarray) -> np.ndarray:
    u, _, vt = np.linalg.svd(r)
    return u @ vt


def _quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a * b of (4,) or (N, 4) quaternions (w, x, y, z); broadcasts."""
    aw, ax, ay, az = np.moveaxis(np.asarray(a), -1, 0)
    bw, bx, by, bz = np.moveaxis(np.asarray(b), -1, 0)
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


@lru_cache(maxsize=1)
def _sample_directions() -> np.ndarray:
    """(64, 3) fixed unit directions, enough to pin every band's (2l+1)^2 rotation matrix."""
    rng = np.random.default_rng(0)
    d = rng.normal(size=(64, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def sh_band_rotations(rotation: np.ndarray, degree: int) -> list[np.ndarray]:
    """Per band l = 1..degree the (2l+1, 2l+1) matrix M_l with c' = M_l c for the band's
    coefficients of a splat rotated by `rotation`.

    Why fitted instead of Wigner-D formulas: each band of real SH is closed under rotation, so
    B_l(R^T d) = B_l(d) A_l for an exact A_l, found by least squares from the project's own basis
    (`render.sh.sh_basis`, 3DGS signs) at a few dozen directions; the colour condition
    B_l(d') c' = B_l(R^T d') c for every rotated direction d' then gives c' = A_l c.
    """
    from bayesian_fields_core.geometry.spherical_harmonics import sh_basis

    d = _sample_directions()
    back = d @ np.asarray(rotation, dtype=np.float64)  # rows R^T d
    b = sh_basis(d, degree)
    b_back = sh_basis(back, degree)
    out = []
    for band in range(1, degree + 1):
        cols = slice(band * band, (band + 1) * (band + 1))
        a, *_ = np.linalg.lstsq(b[:, cols], b_back[:, cols], rcond=None)
        out.append(a)
    return out


def rotate_sh(sh: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """(N, K, 3) SH coefficients of a splat rotated by `rotation`; the DC band is unchanged."""
    degree = int(round(np.sqrt(sh.shape[1]))) - 1
    out = sh.astype(np.float32, copy=True)
    for band, a in enumerate(sh_band_rotations(rotation, degree), start=1):
        cols = slice(band * band, (band + 1) * (band + 1))
        out[:, cols, :] = np.einsum("ij,njc->nic", a, sh[:, cols, :].astype(np.float64)).astype(np.float32)
    return out
