"""Which Gaussians each mask of a frame sees: projection, depth test, label lookup.

A Gaussian is associated with mask `L_i` when its centre projects inside the image onto a pixel
labelled `i` and is not occluded, i.e. its camera-space depth agrees with the depth image at that
pixel (paper Sec. 4.3, following Semantic Gaussians). Everything is one vectorised pass over the
Gaussians per frame, as torch ops on whatever device the centres live on: the CPU for the CLI, the
GPU for a GPU worker, where the rendered depth never leaves the device.

Pixel convention: pixel (row v, column u) covers `[u, u+1) x [v, v+1)` in image coordinates, so
a projection `(x, y)` lands in pixel `(floor(y), floor(x))` (COLMAP / 3DGS convention).

Arithmetic: float64 (camera matrices are float64 and large scene coordinates lose pixels in
float32), and every camera-space coordinate is three scalar multiplies and three adds, each its
own correctly rounded op. A matrix product would hand the rounding to the BLAS library (OpenBLAS
chains fused multiply-adds, MKL does not, cuBLAS does), so the same frame could give a different
last bit on a worker's GPU than in a CPU test; separate ops give the same bits on every device.
"""

from __future__ import annotations

import numpy as np
import torch

from bayesian_fields_core.errors import InputError, InvariantError
from bayesian_fields_core.fusion.tensors import as_tensor
from bayesian_fields_core.params import default

DEFAULT_NEAR = 1e-3
"""Centres closer than this to the camera plane (scene units) are treated as behind it."""


def centre_columns(means: np.ndarray | torch.Tensor, device: torch.device | str) -> torch.Tensor:
    """(3, N) float64 rows x, y, z of the (N, 3) Gaussian centres, on `device`.

    Made once per job, not per frame: converting millions of centres every frame cost more than
    projecting them, and contiguous rows keep each multiply-add a streaming pass.
    """
    means = as_tensor(means, device)
    if means.ndim != 2 or means.shape[1] != 3:
        raise InvariantError(f"expected (N, 3), got {tuple(means.shape)}", source="visibility.means")
    return means.to(torch.float64).T.contiguous()


def camera_row(centres: torch.Tensor, world_to_camera: np.ndarray, row: int) -> torch.Tensor:
    """Camera-space coordinate `row` (0 x, 1 y, 2 z) of (3, n) centres: (n,) float64.

    `w[row, 0] x + w[row, 1] y + w[row, 2] z + w[row, 3]`, left to right, one rounding per op
    (in place, through one scratch buffer: fresh buffers per op cost more than the arithmetic).
    """
    w = [float(v) for v in np.asarray(world_to_camera, dtype=np.float64)[row]]
    out = centres[0] * w[0]
    scratch = torch.empty_like(out)
    out += torch.mul(centres[1], w[1], out=scratch)
    out += torch.mul(centres[2], w[2], out=scratch)
    out += w[3]
    return out


def _check_inputs(
    centres: torch.Tensor,
    K: np.ndarray,
    w2c: np.ndarray,
    width: int,
    height: int,
    depth: torch.Tensor,
    labels: torch.Tensor,
) -> None:
    if centres.ndim != 2 or centres.shape[0] != 3 or centres.dtype != torch.float64:
        raise InvariantError(
            f"expected (3, N) float64 (`centre_columns`), got {tuple(centres.shape)} {centres.dtype}",
            source="visibility.centres",
        )
    if K.shape != (3, 3):
        raise InvariantError(f"expected (3, 3), got {K.shape}", source="visibility.K")
    if w2c.shape != (4, 4):
        raise InvariantError(f"expected (4, 4), got {w2c.shape}", source="visibility.world_to_camera")
    for name, image in (("depth", depth), ("labels", labels)):
        if tuple(image.shape) != (height, width):
            raise InvariantError(
                f"expected ({height}, {width}), got {tuple(image.shape)}", source=f"visibility.{name}"
            )


def mask_associations(
    centres: torch.Tensor,
    K: np.ndarray,
    w2c: np.ndarray,
    width: int,
    height: int,
    depth: np.ndarray | torch.Tensor,
    labels: np.ndarray | torch.Tensor,
    *,
    depth_tolerance: float,
    relative_tolerance: float = default("depth_tolerance_relative"),
    near: float = DEFAULT_NEAR,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Pairs (gaussian_ids int64 (n,), mask_ids int32 (n,)) of visible Gaussians and their mask.

    centres: (3, N) float64 from `centre_columns`; the pairs come back on its device, and `depth`
    (H, W) float and `labels` (H, W) integer (numpy arrays or tensors) are moved there.
    Visible: in front of the camera (`z > near`), projecting inside the image, onto a pixel with
    depth `d > 0` (0 means nothing was rendered there) and
    `|z - d| <= depth_tolerance + relative_tolerance * d`. Only pixels with a label `>= 0` yield a
    pair. Each Gaussian projects to one pixel, so it appears at most once (ids ascending).
    `depth_tolerance` and `near` are lengths in scene units: the fuse stage passes the run's
    `SceneLengths` (fractions of the scene scale), so it has no default here.
    """
    K = np.asarray(K, dtype=np.float64)
    w2c = np.asarray(w2c, dtype=np.float64)
    depth = as_tensor(depth, centres.device)
    labels = as_tensor(labels, centres.device)
    _check_inputs(centres, K, w2c, width, height, depth, labels)
    if depth_tolerance < 0 or relative_tolerance < 0:
        raise InputError("depth tolerances must be >= 0", source="visibility.depth_tolerance")

    z = camera_row(centres, w2c, 2)
    front = torch.nonzero(z > near).squeeze(1)  # cull first: about half the scene is behind the camera
    seen, z = centres.index_select(1, front), z.index_select(0, front)
    xn, yn = camera_row(seen, w2c, 0) / z, camera_row(seen, w2c, 1) / z
    x = float(K[0, 0]) * xn + float(K[0, 1]) * yn + float(K[0, 2])
    y = float(K[1, 1]) * yn + float(K[1, 2])
    inside = torch.nonzero((x >= 0) & (x < width) & (y >= 0) & (y < height)).squeeze(1)
    candidates, z = front.index_select(0, inside), z.index_select(0, inside)
    # truncation = floor: the coordinates are >= 0 here
    flat = y.index_select(0, inside).long() * width + x.index_select(0, inside).long()
    pixel_label = labels.reshape(-1).index_select(0, flat)
    pixel_depth = depth.reshape(-1).index_select(0, flat).to(torch.float64)
    tolerance = depth_tolerance + relative_tolerance * pixel_depth
    visible = (pixel_label >= 0) & (pixel_depth > 0) & ((z - pixel_depth).abs() <= tolerance)
    keep = torch.nonzero(visible).squeeze(1)
    return candidates.index_select(0, keep), pixel_label.index_select(0, keep).to(torch.int32)
