"""EWA splatting: 3D Gaussians -> screen-space ellipses for one pinhole camera.

Each 3D covariance Sigma = R S S^T R^T is pushed through the linearised perspective projection
(Zwicker et al.'s EWA, as in 3DGS): Sigma2D = J W Sigma W^T J^T + eps2d I, with W the camera
rotation and J the Jacobian of (x, y, z) -> (fx x/z + cx, fy y/z + cy) at the Gaussian mean.
Pixel convention: pixel (row i, col j) covers [j, j+1) x [i, i+1), so its centre is at
(j + 0.5, i + 0.5) and a point projecting to (u, v) lies in pixel (floor(v), floor(u)); this is
the COLMAP / 3DGS / gsplat convention the scene readers deliver.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from bayesian_fields_core.render.output import RasterSettings


def quaternion_to_rotation(quats: torch.Tensor) -> torch.Tensor:
    """Rotation matrices (N, 3, 3) from (w, x, y, z) quaternions, normalised here."""
    q = quats / quats.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    w, x, y, z = q.unbind(-1)
    rows = [
        1 - 2 * (y * y + z * z),
        2 * (x * y - w * z),
        2 * (x * z + w * y),
        2 * (x * y + w * z),
        1 - 2 * (x * x + z * z),
        2 * (y * z - w * x),
        2 * (x * z - w * y),
        2 * (y * z + w * x),
        1 - 2 * (x * x + y * y),
    ]
    return torch.stack(rows, dim=-1).reshape(-1, 3, 3)


def covariance_3d(log_scales: torch.Tensor, quats: torch.Tensor) -> torch.Tensor:
    """World-space covariances (N, 3, 3) = R S S^T R^T with S = diag(exp(log_scales))."""
    m = quaternion_to_rotation(quats) * torch.exp(log_scales)[:, None, :]
    return m @ m.transpose(1, 2)


@dataclass
class Projected:
    """The Gaussians that survived culling, in screen space (all tensors share the first axis).

    ids: indices into the renderer's Gaussians. xy: (M, 2) projected means (pixels).
    conic: (M, 3) the inverse 2D covariance as (a, b, c) = [[a, b], [b, c]].
    depth: (M,) camera z. opacity: (M,). rect: (M, 4) int64 inclusive tile range
    (x0, y0, x1, y1) touched by the sigma_extent box.
    """

    ids: torch.Tensor
    xy: torch.Tensor
    conic: torch.Tensor
    depth: torch.Tensor
    opacity: torch.Tensor
    rect: torch.Tensor


def project(
    means: torch.Tensor,
    cov3d: torch.Tensor,
    opacity: torch.Tensor,
    K: torch.Tensor,
    world_to_camera: torch.Tensor,
    width: int,
    height: int,
    settings: RasterSettings,
) -> Projected:
    """Cull (near plane, faint, off-screen, degenerate) and project the Gaussians to the image.

    K and world_to_camera are float64 tensors on the Gaussians' device; the camera-space means
    are computed in float64 so scenes with large world coordinates keep their precision.
    """
    rot = world_to_camera[:3, :3]
    p_cam = (means.double() @ rot.T + world_to_camera[:3, 3]).float()
    z = p_cam[:, 2]
    keep = (z > settings.near_plane) & (opacity >= settings.min_alpha)
    ids = torch.nonzero(keep).squeeze(1)
    p_cam, z = p_cam[ids], z[ids]

    fx, fy, cx, cy = (float(v) for v in (K[0, 0], K[1, 1], K[0, 2], K[1, 2]))
    # Clamp the direction used by the Jacobian to fov_clamp x the (possibly off-centre) frustum.
    lim = settings.fov_clamp
    tx = (p_cam[:, 0] / z).clamp(-lim * cx / fx, lim * (width - cx) / fx) * z
    ty = (p_cam[:, 1] / z).clamp(-lim * cy / fy, lim * (height - cy) / fy) * z
    zero = torch.zeros_like(z)
    jac = torch.stack([fx / z, zero, -fx * tx / (z * z), zero, fy / z, -fy * ty / (z * z)], dim=-1).reshape(
        -1, 2, 3
    )
    t = jac @ rot.float()
    cov2 = t @ cov3d[ids] @ t.transpose(1, 2)
    a = cov2[:, 0, 0] + settings.eps2d
    b = cov2[:, 0, 1]
    c = cov2[:, 1, 1] + settings.eps2d
    det = a * c - b * b

    mid = 0.5 * (a + c)
    lambda_max = mid + torch.sqrt((mid * mid - det).clamp_min(0.1))
    radius = torch.ceil(settings.sigma_extent * torch.sqrt(lambda_max))
    u = fx * p_cam[:, 0] / z + cx
    v = fy * p_cam[:, 1] / z + cy

    tile = settings.tile_size
    tiles_x = (width + tile - 1) // tile
    tiles_y = (height + tile - 1) // tile
    on_screen = (u + radius >= 0) & (u - radius < width) & (v + radius >= 0) & (v - radius < height)
    ok = (det > 0) & on_screen
    sel = torch.nonzero(ok).squeeze(1)
    u, v, radius, a, b, c, det = (x[sel] for x in (u, v, radius, a, b, c, det))
    rect = torch.stack(
        [
            torch.floor((u - radius) / tile).clamp(0, tiles_x - 1),
            torch.floor((v - radius) / tile).clamp(0, tiles_y - 1),
            torch.floor((u + radius) / tile).clamp(0, tiles_x - 1),
            torch.floor((v + radius) / tile).clamp(0, tiles_y - 1),
        ],
        dim=-1,
    ).long()
    ids = ids[sel]
    return Projected(
        ids=ids,
        xy=torch.stack([u, v], dim=-1),
        conic=torch.stack([c / det, -b / det, a / det], dim=-1),
        depth=z[sel],
        opacity=opacity[ids],
        rect=rect,
    )
