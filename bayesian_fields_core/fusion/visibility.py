"""Which Gaussians each mask of a frame sees: projection, depth test, label lookup.

A Gaussian is associated with mask `L_i` when its centre projects inside the image onto a pixel
labelled `i` and is not occluded, i.e. its camera-space depth agrees with the depth image at that
pixel (paper Sec. 4.3, following Semantic Gaussians). Everything is one vectorised pass over the
Gaussians per frame.

Pixel convention: pixel (row v, column u) covers `[u, u+1) x [v, v+1)` in image coordinates, so
a projection `(x, y)` lands in pixel `(floor(y), floor(x))` (COLMAP / 3DGS convention).
"""

from __future__ import annotations

import numpy as np

from bayesian_fields_core.errors import InputError, InvariantError
from bayesian_fields_core.params import default

DEFAULT_NEAR = 1e-3
"""Centres closer than this to the camera plane (scene units) are treated as behind it."""


def camera_coordinates(means: np.ndarray, world_to_camera: np.ndarray) -> np.ndarray:
    """(3, N) float64 camera-space coordinates of (N, 3) world points.

    float64 because camera matrices are float64 and large scene coordinates lose pixels in
    float32; the (3, 3) @ (3, N) layout keeps the product on the BLAS path (an (N, 3) @ (3, 3)
    with a transposed operand is an order of magnitude slower for millions of points).
    """
    R = np.asarray(world_to_camera[:3, :3], dtype=np.float64)
    t = np.asarray(world_to_camera[:3, 3], dtype=np.float64)
    return R @ np.asarray(means, dtype=np.float64).T + t[:, None]


def _check_inputs(
    means: np.ndarray,
    K: np.ndarray,
    w2c: np.ndarray,
    width: int,
    height: int,
    depth: np.ndarray,
    labels: np.ndarray,
) -> None:
    if means.ndim != 2 or means.shape[1] != 3:
        raise InvariantError(f"expected (N, 3), got {means.shape}", source="visibility.means")
    if K.shape != (3, 3):
        raise InvariantError(f"expected (3, 3), got {K.shape}", source="visibility.K")
    if w2c.shape != (4, 4):
        raise InvariantError(f"expected (4, 4), got {w2c.shape}", source="visibility.world_to_camera")
    for name, image in (("depth", depth), ("labels", labels)):
        if image.shape != (height, width):
            raise InvariantError(
                f"expected ({height}, {width}), got {image.shape}", source=f"visibility.{name}"
            )


def mask_associations(
    means: np.ndarray,
    K: np.ndarray,
    w2c: np.ndarray,
    width: int,
    height: int,
    depth: np.ndarray,
    labels: np.ndarray,
    *,
    depth_tolerance: float = default("depth_tolerance"),
    relative_tolerance: float = default("depth_tolerance_relative"),
    near: float = DEFAULT_NEAR,
) -> tuple[np.ndarray, np.ndarray]:
    """Pairs (gaussian_ids int64 (n,), mask_ids int32 (n,)) of visible Gaussians and their mask.

    Visible: in front of the camera (`z > near`), projecting inside the image, onto a pixel with
    rendered depth `d > 0` (0 means nothing was rendered there) and
    `|z - d| <= depth_tolerance + relative_tolerance * d`. Only pixels with a label `>= 0` yield a
    pair. Each Gaussian projects to one pixel, so it appears at most once (ids ascending).
    """
    means = np.asarray(means)
    depth = np.asarray(depth)
    labels = np.asarray(labels)
    _check_inputs(means, np.asarray(K), np.asarray(w2c), width, height, depth, labels)
    if depth_tolerance < 0 or relative_tolerance < 0:
        raise InputError("depth tolerances must be >= 0", source="visibility.depth_tolerance")

    K = np.asarray(K, dtype=np.float64)
    cam = camera_coordinates(means, np.asarray(w2c, dtype=np.float64))
    front = np.flatnonzero(cam[2] > near)  # cull first: about half the scene is behind the camera
    z = cam[2, front]
    xn, yn = cam[0, front] / z, cam[1, front] / z
    x = K[0, 0] * xn + K[0, 1] * yn + K[0, 2]
    y = K[1, 1] * yn + K[1, 2]
    inside = (x >= 0) & (x < width) & (y >= 0) & (y < height)
    candidates = front[inside]
    x, y, z = x[inside], y[inside], z[inside]
    u = x.astype(np.int64)  # floor: coordinates are non-negative here
    v = y.astype(np.int64)
    flat = v * width + u
    pixel_label = labels.reshape(-1)[flat]
    pixel_depth = depth.reshape(-1)[flat].astype(np.float64)
    tolerance = depth_tolerance + relative_tolerance * pixel_depth
    visible = (pixel_label >= 0) & (pixel_depth > 0) & (np.abs(z - pixel_depth) <= tolerance)
    return candidates[visible].astype(np.int64), pixel_label[visible].astype(np.int32)
