"""gsplat's world normalisation (`normalize_world_space=True`, its default), recomputed from
the COLMAP model, because gsplat does not save the transform it applied.

gsplat's COLMAP parser maps the world to the trained splat's frame with one similarity built in
three steps (the mathematics of its `similarity_from_cameras`, `align_principal_axes` and the
upside-down fix; written here from their definitions, not copied):
  1. camera similarity: rotate the mean camera "up" (-y of each OpenCV camera, in the world)
     onto +z; translate by minus the median over cameras of the point of each optical axis
     nearest the origin (the "focus" centre); scale by 1 / the median camera distance to it;
  2. when the model has 3D points: rotate about their median so their principal axes (largest
     variance first, eigenvectors of their covariance, a proper rotation) become x, y, z;
  3. when, after that, the points' median z exceeds their mean z, turn 180 degrees about x.
The result is world -> splat; the scene loader applies its inverse to the Gaussians.
"""

from __future__ import annotations

import numpy as np

from bayesian_fields_core.scene.similarity import Similarity


def _rotation_onto(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation taking unit vector a onto unit vector b (180 degrees about x when
    they are opposite, as gsplat does)."""
    c = float(a @ b)
    if c <= -1.0 + 1e-12:
        return np.diag([1.0, -1.0, -1.0])
    v = np.cross(a, b)
    k = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    return np.eye(3) + k + k @ k / (1.0 + c)


def camera_similarity(camera_to_world: np.ndarray) -> Similarity:
    """Step 1 of the module docstring, from (N, 4, 4) OpenCV camera-to-world poses."""
    rot, centres = camera_to_world[:, :3, :3], camera_to_world[:, :3, 3]
    up = (rot @ np.array([0.0, -1.0, 0.0])).mean(axis=0)
    align = _rotation_onto(up / np.linalg.norm(up), np.array([0.0, 0.0, 1.0]))
    forward = (align @ rot)[:, :, 2]
    t = centres @ align.T
    nearest = t + ((-t * forward).sum(axis=1))[:, None] * forward
    translate = -np.median(nearest, axis=0)
    scale = 1.0 / float(np.median(np.linalg.norm(t + translate, axis=1)))
    return Similarity(scale, align, scale * translate)


def principal_axes(points: np.ndarray) -> Similarity:
    """Step 2: rotation about the median taking the principal axes onto x, y, z."""
    centre = np.median(points, axis=0)
    values, vectors = np.linalg.eigh(np.cov(points - centre, rowvar=False))
    vectors = vectors[:, np.argsort(values)[::-1]]
    if np.linalg.det(vectors) < 0:
        vectors[:, 0] = -vectors[:, 0]
    return Similarity(1.0, vectors.T, -vectors.T @ centre)


def gsplat_world_to_splat(camera_to_world: np.ndarray, points: np.ndarray) -> Similarity:
    """World -> gsplat's normalised frame (the three steps of the module docstring)."""
    transform = camera_similarity(camera_to_world)
    if len(points) < 3:
        return transform
    transform = transform.then(principal_axes(transform.points(points)))
    moved = transform.points(points)
    if np.median(moved[:, 2]) > np.mean(moved[:, 2]):
        transform = transform.then(Similarity(1.0, np.diag([1.0, -1.0, -1.0]), np.zeros(3)))
    return transform
