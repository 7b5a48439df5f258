"""Render a Gaussian splat from a pinhole camera: colour, expected/median depth and alpha.

`GaussianRenderer` converts the splat to device tensors once (normalised quaternions, scales,
opacities, view-independent 3D covariances) so that fusion can render hundreds of frames without
re-conversion. The torch backend (CPU or CUDA) implements the 3DGS forward pass: EWA projection,
tile binning, depth-sorted front-to-back compositing; with backend "auto" the gsplat CUDA
rasteriser is used instead when it is installed and a GPU is present; its median depth comes
from gsplat's own traversal too (`gsplat_median`), so no torch rasteriser runs on that path.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Literal

import numpy as np
import torch

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.render.composite import composite
from bayesian_fields_core.render.gsplat_backend import gsplat_available, median_depth_gsplat, rasterize_gsplat
from bayesian_fields_core.render.output import RasterSettings, RenderOutput
from bayesian_fields_core.render.projection import covariance_3d, project
from bayesian_fields_core.render.sh import sh_to_rgb
from bayesian_fields_core.render.tiles import bin_gaussians, faint_cull
from bayesian_fields_core.scene.types import Gaussians

Backend = Literal["auto", "torch", "gsplat"]


def _check_gaussians(g: Gaussians) -> None:
    n = len(g)
    expected = {
        "means": (n, 3),
        "log_scales": (n, 3),
        "quats": (n, 4),
        "opacity_logits": (n,),
    }
    for name, shape in expected.items():
        arr = np.asarray(getattr(g, name))
        if arr.shape != shape:
            raise InputError(f"expected shape {shape}, got {arr.shape}", source=f"gaussians.{name}")
    sh = np.asarray(g.sh)
    if sh.ndim != 3 or sh.shape[0] != n or sh.shape[2] != 3 or sh.shape[1] not in (1, 4, 9, 16):
        raise InputError(
            f"expected (N, K, 3) with K in 1/4/9/16 (SH degree 0..3), got {sh.shape}",
            source="gaussians.sh",
        )


def _check_camera(K: np.ndarray, w2c: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    K = np.asarray(K, dtype=np.float64)
    w2c = np.asarray(w2c, dtype=np.float64)
    if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise InputError(f"expected a finite (3, 3) pinhole matrix with fx, fy > 0, got {K!r}", source="K")
    if w2c.shape != (4, 4) or not np.all(np.isfinite(w2c)):
        raise InputError(f"expected a finite (4, 4) matrix, got shape {w2c.shape}", source="world_to_camera")
    if int(width) != width or int(height) != height or width <= 0 or height <= 0:
        raise InputError(f"image size must be positive integers, got {width}x{height}", source="width/height")
    return K, w2c


def _check_background(background: Sequence[float]) -> np.ndarray:
    bg = np.asarray(background, dtype=np.float32).reshape(-1)
    if bg.shape != (3,) or not np.all(np.isfinite(bg)):
        raise InputError(f"expected 3 finite RGB values, got {background!r}", source="background")
    return bg


def _resolve_device(device: str | torch.device) -> torch.device:
    dev = torch.device(device)
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise InputError("CUDA was requested but is not available", source="device")
    return dev


class GaussianRenderer:
    """Renders one splat from many cameras, keeping its tensors resident on `device`.

    backend: "torch" (always available, CPU or CUDA), "gsplat" (needs gsplat and CUDA), or
    "auto" (gsplat when it is importable and CUDA is available, else torch).
    settings: rasterisation constants (near plane, tile/chunk sizes, memory cap, ...).
    near_plane: overrides `settings.near_plane`; the pipeline passes a fraction of the scene
        scale (`scene.scale.SceneLengths.render_near`), so the culled shell follows the scene's
        units instead of a fixed 1 cm.
    """

    def __init__(
        self,
        gaussians: Gaussians,
        device: str | torch.device = "cpu",
        backend: Backend = "auto",
        *,
        settings: RasterSettings | None = None,
        near_plane: float | None = None,
    ) -> None:
        _check_gaussians(gaussians)
        if backend not in ("auto", "torch", "gsplat"):
            raise InputError(f"unknown backend {backend!r} (auto, torch, gsplat)", source="backend")
        self.device = _resolve_device(device)
        if backend == "auto":
            backend = "gsplat" if self.device.type == "cuda" and gsplat_available() else "torch"
        elif backend == "gsplat" and not (self.device.type == "cuda" and gsplat_available()):
            raise InputError("backend 'gsplat' needs the gsplat package and a CUDA device", source="backend")
        self.backend: str = backend
        self.settings = settings or RasterSettings()
        if near_plane is not None:
            if not np.isfinite(near_plane) or near_plane <= 0:
                raise InputError(
                    f"near plane must be a positive finite length, got {near_plane!r}", source="near_plane"
                )
            self.settings = dataclasses.replace(self.settings, near_plane=float(near_plane))

        def to_dev(a: np.ndarray) -> torch.Tensor:
            return torch.as_tensor(np.ascontiguousarray(a, dtype=np.float32), device=self.device)

        self.means = to_dev(gaussians.means)
        self.quats = to_dev(gaussians.quats)
        self.quats = self.quats / self.quats.norm(dim=-1, keepdim=True).clamp_min(1e-12)
        log_scales = to_dev(gaussians.log_scales)
        self.scales = torch.exp(log_scales)
        self.opacities = torch.sigmoid(to_dev(gaussians.opacity_logits))
        self.sh = to_dev(gaussians.sh)
        self.cov3d = covariance_3d(log_scales, self.quats)

    def __len__(self) -> int:
        return int(self.means.shape[0])

    def render(
        self,
        K: np.ndarray,
        world_to_camera: np.ndarray,
        width: int,
        height: int,
        *,
        background: Sequence[float] = (0.0, 0.0, 0.0),
        depth_only: bool = False,
    ) -> RenderOutput:
        """Render one view; `depth_only` skips colour (and SH evaluation) and returns rgb=None."""
        rgb, depth, median, alpha = self.render_tensors(
            K, world_to_camera, width, height, background=background, depth_only=depth_only
        )

        def to_np(t: torch.Tensor) -> np.ndarray:
            return np.ascontiguousarray(t.detach().float().cpu().numpy())

        return RenderOutput(
            rgb=None if rgb is None else to_np(rgb),
            depth=to_np(depth),
            median_depth=to_np(median),
            alpha=to_np(alpha),
        )

    def render_tensors(
        self,
        K: np.ndarray,
        world_to_camera: np.ndarray,
        width: int,
        height: int,
        *,
        background: Sequence[float] = (0.0, 0.0, 0.0),
        depth_only: bool = False,
    ) -> tuple[torch.Tensor | None, torch.Tensor, torch.Tensor, torch.Tensor]:
        """(rgb (H,W,3) | None, depth, median depth, alpha (H,W)) as float32 tensors on `device`.

        What `render` returns, left on the device: the CUDA fusion path reads the depth where it
        was rendered instead of copying every frame to the host and back.
        """
        K, w2c = _check_camera(K, world_to_camera, width, height)
        bg = _check_background(background)
        width, height = int(width), int(height)
        K_t = torch.as_tensor(K, device=self.device)
        w2c_t = torch.as_tensor(w2c, device=self.device)
        s = self.settings
        with torch.no_grad():
            if self.backend == "gsplat":
                rgb, depth, alpha, meta = rasterize_gsplat(
                    self.means,
                    self.quats,
                    self.scales,
                    self.opacities,
                    self.sh,
                    K_t,
                    w2c_t,
                    width,
                    height,
                    near_plane=s.near_plane,
                    eps2d=s.eps2d,
                    tile_size=s.tile_size,
                    depth_only=depth_only,
                )
                median = median_depth_gsplat(
                    meta, width, height, level=s.median_transmittance, max_alpha=s.max_alpha
                )
            else:
                rgb, depth, median, alpha = self._render_torch(
                    K_t, w2c_t, width, height, depth_only=depth_only
                )
            if rgb is not None:
                rgb = (rgb + (1.0 - alpha)[..., None] * torch.as_tensor(bg, device=self.device)).clamp_(
                    0.0, 1.0
                )
            depth = torch.where(alpha >= s.min_depth_alpha, depth, torch.zeros_like(depth))
        return rgb, depth, median, alpha

    def _render_torch(
        self, K: torch.Tensor, w2c: torch.Tensor, width: int, height: int, *, depth_only: bool
    ) -> tuple[torch.Tensor | None, torch.Tensor, torch.Tensor, torch.Tensor]:
        """(rgb without background | None, expected depth, median depth, alpha), each (H, W[, 3])."""
        s = self.settings
        proj = project(self.means, self.cov3d, self.opacities, K, w2c, width, height, s)
        if depth_only:
            features = proj.depth[:, None]
        else:
            centre = torch.linalg.inv(w2c)[:3, 3].float()
            colours = sh_to_rgb(self.sh[proj.ids], self.means[proj.ids], centre)
            features = torch.cat([colours, proj.depth[:, None]], dim=1)
        tiles_x = (width + s.tile_size - 1) // s.tile_size
        tiles_y = (height + s.tile_size - 1) // s.tile_size
        bins = bin_gaussians(proj.rect, proj.depth, tiles_x, tiles_x * tiles_y, faint_cull(proj, s))
        out = composite(proj.xy, proj.conic, proj.opacity, proj.depth, features, bins, tiles_x, tiles_y, s)
        feats = out.features[:height, :width]
        alpha = 1.0 - out.transmittance[:height, :width]
        depth = feats[..., -1] / alpha.clamp_min(1e-12)
        rgb = None if depth_only else feats[..., :3]
        return rgb, depth, out.median_depth[:height, :width], alpha


def render(
    gaussians: Gaussians,
    K: np.ndarray,
    world_to_camera: np.ndarray,
    width: int,
    height: int,
    *,
    background: Sequence[float] = (0.0, 0.0, 0.0),
    device: str | torch.device = "cpu",
    backend: Backend = "auto",
    depth_only: bool = False,
    settings: RasterSettings | None = None,
) -> RenderOutput:
    """One-off render; build a `GaussianRenderer` instead when rendering several views."""
    renderer = GaussianRenderer(gaussians, device=device, backend=backend, settings=settings)
    return renderer.render(K, world_to_camera, width, height, background=background, depth_only=depth_only)
