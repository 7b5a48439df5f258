"""Camera geometry shared by the camera-format readers and writers.

Each format stores poses differently (COLMAP: world-to-camera quaternion; nerfstudio: OpenGL
camera-to-world matrix; INRIA: camera-to-world rotation + centre). Converting through these few
vectorized helpers keeps every reader a thin parser and every conversion tested once.
"""

from __future__ import annotations

import numpy as np

OPENGL_TO_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])
"""Flips y and z: OpenGL camera axes (x right, y up, z back) <-> OpenCV (x right, y down, z forward)."""

RIGID_TOLERANCE = 1e-3
"""Largest |R^T R - I| entry accepted for a rotation read from a file (files store ~7 digits)."""


def intrinsics(fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """The (3, 3) float64 pinhole matrix."""
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]], dtype=np.float64)


def quat_to_rotmat(q: np.ndarray) -> np.ndarray:
    """(..., 4) quaternions (w, x, y, z), normalised here, -> (..., 3, 3) rotation matrices."""
    q = np.asarray(q, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    rows = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]
    return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)


def rotmat_to_quat(r: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices -> (..., 4) unit quaternions (w, x, y, z) with w >= 0.

    Uses the eigenvector of the symmetric 4x4 matrix of Bar-Itzhack, which is robust for every
    rotation (no branch on the largest diagonal element) and vectorizes through `np.linalg.eigh`.
    """
    r = np.swapaxes(np.asarray(r, dtype=np.float64), -1, -2)  # the paper's index convention
    xx, xy, xz = r[..., 0, 0], r[..., 0, 1], r[..., 0, 2]
    yx, yy, yz = r[..., 1, 0], r[..., 1, 1], r[..., 1, 2]
    zx, zy, zz = r[..., 2, 0], r[..., 2, 1], r[..., 2, 2]
    k = (
        np.stack(
            [
                np.stack([xx - yy - zz, yx + xy, zx + xz, yz - zy], axis=-1),
                np.stack([yx + xy, yy - xx - zz, zy + yz, zx - xz], axis=-1),
                np.stack([zx + xz, zy + yz, zz - xx - yy, xy - yx], axis=-1),
                np.stack([yz - zy, zx - xz, xy - yx, xx + yy + zz], axis=-1),
            ],
            axis=-2,
        )
        / 3.0
    )
    _, vecs = np.linalg.eigh(k)
    xyzw = vecs[..., :, -1]  # eigenvector of the largest eigenvalue, ordered (x, y, z, w)
    q = np.concatenate([xyzw[..., 3:4], xyzw[..., :3]], axis=-1)
    return q * np.where(q[..., :1] < 0, -1.0, 1.0)


def rigid(rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """(..., 4, 4) transforms from (..., 3, 3) rotations and (..., 3) translations."""
    rotation = np.asarray(rotation, dtype=np.float64)
    out = np.zeros(rotation.shape[:-2] + (4, 4), dtype=np.float64)
    out[..., :3, :3] = rotation
    out[..., :3, 3] = translation
    out[..., 3, 3] = 1.0
    return out


def invert_rigid(t: np.ndarray) -> np.ndarray:
    """Inverse of (..., 4, 4) rigid transforms, exact in R^T form (no general matrix inverse)."""
    rt = np.swapaxes(t[..., :3, :3], -1, -2)
    return rigid(rt, -np.einsum("...ij,...j->...i", rt, t[..., :3, 3]))


def rotation_error(rotation: np.ndarray) -> np.ndarray:
    """Per-matrix max |R^T R - I| and |det R - 1|: how far (..., 3, 3) is from a rotation."""
    rotation = np.asarray(rotation, dtype=np.float64)
    ortho = np.abs(np.swapaxes(rotation, -1, -2) @ rotation - np.eye(3)).max(axis=(-1, -2))
    return np.maximum(ortho, np.abs(np.linalg.det(rotation) - 1.0))


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray = np.array([0.0, 0.0, 1.0])) -> np.ndarray:
    """World-to-camera (4, 4) for a camera at eye looking at target, x right, y down, z forward."""
    forward = target - eye
    forward = forward / np.linalg.norm(forward)
    right = np.cross(forward, up)
    norm = np.linalg.norm(right)
    if norm < 1e-9:
        raise ValueError("look_at: viewing direction is parallel to the up vector")
    right /= norm
    down = np.cross(forward, right)
    c2w_rot = np.stack([right, down, forward], axis=1)
    return rigid(c2w_rot.T, -c2w_rot.T @ eye)


def pinhole(width: int, height: int, fov_deg: float) -> np.ndarray:
    """Intrinsics with square pixels, principal point at the centre, given horizontal FOV."""
    f = 0.5 * width / np.tan(np.deg2rad(fov_deg) / 2)
    return intrinsics(f, f, width / 2, height / 2)
