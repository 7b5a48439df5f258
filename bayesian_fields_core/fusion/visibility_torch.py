"""`visibility.mask_associations` as torch ops, for a worker whose depth images live on a GPU.

Same rule, same float64 camera transform and the same pixel convention as the numpy version (the
CPU path), so both return the same pairs; here every step stays on the tensors' device, and the
rendered depth never travels to the host. The inputs are checked by the caller's numpy twin's
rules: shapes are validated here with the same messages.
"""

from __future__ import annotations

import numpy as np
import torch

from bayesian_fields_core.errors import InputError, InvariantError
from bayesian_fields_core.fusion.visibility import DEFAULT_NEAR
from bayesian_fields_core.params import default


def camera_coordinates_torch(means: torch.Tensor, world_to_camera: np.ndarray) -> torch.Tensor:
    """(3, N) float64 camera-space coordinates of (N, 3) world points, on `means.device`."""
    w2c = torch.as_tensor(np.asarray(world_to_camera, dtype=np.float64), device=means.device)
    return w2c[:3, :3] @ means.double().T + w2c[:3, 3:4]


def mask_associations_torch(
    means: torch.Tensor,
    K: np.ndarray,
    w2c: np.ndarray,
    width: int,
    height: int,
    depth: torch.Tensor,
    labels: torch.Tensor,
    *,
    depth_tolerance: float = default("depth_tolerance"),
    relative_tolerance: float = default("depth_tolerance_relative"),
    near: float = DEFAULT_NEAR,
) -> tuple[torch.Tensor, torch.Tensor]:
    """(gaussian_ids int64 (n,), mask_ids int32 (n,)) on the device; see `mask_associations`.

    means (N, 3) float tensor; depth (H, W) float and labels (H, W) integer tensors on the same
    device. Visible: `z > near`, inside the image, rendered depth `d > 0` and
    `|z - d| <= depth_tolerance + relative_tolerance * d`, label >= 0; ids ascending.
    """
    if means.ndim != 2 or means.shape[1] != 3:
        raise InvariantError(f"expected (N, 3), got {tuple(means.shape)}", source="visibility.means")
    for name, image in (("depth", depth), ("labels", labels)):
        if tuple(image.shape) != (height, width):
            raise InvariantError(
                f"expected ({height}, {width}), got {tuple(image.shape)}", source=f"visibility.{name}"
            )
    if depth_tolerance < 0 or relative_tolerance < 0:
        raise InputError("depth tolerances must be >= 0", source="visibility.depth_tolerance")
    K = np.asarray(K, dtype=np.float64)
    if K.shape != (3, 3):
        raise InvariantError(f"expected (3, 3), got {K.shape}", source="visibility.K")
    cam = camera_coordinates_torch(means, w2c)
    front = torch.nonzero(cam[2] > near).squeeze(1)
    z = cam[2, front]
    xn, yn = cam[0, front] / z, cam[1, front] / z
    x = float(K[0, 0]) * xn + float(K[0, 1]) * yn + float(K[0, 2])
    y = float(K[1, 1]) * yn + float(K[1, 2])
    inside = (x >= 0) & (x < width) & (y >= 0) & (y < height)
    candidates = front[inside]
    x, y, z = x[inside], y[inside], z[inside]
    flat = y.long() * width + x.long()  # truncation = floor: coordinates are non-negative here
    pixel_label = labels.reshape(-1)[flat]
    pixel_depth = depth.reshape(-1)[flat].double()
    tolerance = depth_tolerance + relative_tolerance * pixel_depth
    visible = (pixel_label >= 0) & (pixel_depth > 0) & ((z - pixel_depth).abs() <= tolerance)
    return candidates[visible].long(), pixel_label[visible].int()
