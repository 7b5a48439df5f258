"""View-dependent colour from real spherical harmonics (degree 0..3), as in 3DGS.

A Gaussian's colour is evaluated once per view for the direction from the camera centre to its
mean; the constants are the standard real SH normalisations, and the +0.5 offset / clamp at 0
follow the 3DGS convention so PLY files trained there render with the same colours.
"""

from __future__ import annotations

import torch

from bayesian_fields_core.geometry.spherical_harmonics import sh_basis


def sh_to_rgb(sh: torch.Tensor, means: torch.Tensor, camera_centre: torch.Tensor) -> torch.Tensor:
    """Colours (N, 3) = max(sum_k sh_k * Y_k(dir) + 0.5, 0) with dir = mean - camera centre.

    sh: (N, K, 3) coefficients, K = (degree+1)^2 with degree <= 3.
    """
    degree = int(round(sh.shape[1] ** 0.5)) - 1
    dirs = means - camera_centre
    dirs = dirs / dirs.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    basis = sh_basis(dirs, degree)
    rgb = torch.einsum("nk,nkc->nc", basis, sh) + 0.5
    return rgb.clamp_min_(0.0)
