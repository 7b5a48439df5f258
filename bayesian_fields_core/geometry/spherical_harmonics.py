"""Real spherical harmonics (degree 0..3) in the 3DGS sign convention: the basis and its constants.

Shared by rendering (view-dependent colour, `render.sh`), the similarity transforms that rotate a
splat's SH bands (`scene.similarity`), the result exports and the synthetic scenes, so the
constants are written once. The basis takes numpy arrays or torch tensors alike, and torch is
imported only for tensors: reading a splat (which rotates SH bands) needs no torch.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, TypeVar

import numpy as np

if TYPE_CHECKING:
    import torch

Directions = TypeVar("Directions", np.ndarray, "torch.Tensor")

C0 = 0.28209479177387814
SH_C0 = C0
"""Degree-0 basis constant: a Gaussian's base colour = 0.5 + SH_C0 * f_dc."""
C1 = 0.4886025119029199
C2 = (
    1.0925484305920792,
    -1.0925484305920792,
    0.31539156525252005,
    -1.0925484305920792,
    0.5462742152960396,
)
C3 = (
    -0.5900435899266435,
    2.890611442640554,
    -0.4570457994644658,
    0.3731763325901154,
    -0.4570457994644658,
    1.445305721320277,
    -0.5900435899266435,
)


def sh_basis(dirs: Directions, degree: int) -> Directions:
    """Real SH basis values (N, (degree+1)^2) for unit directions (N, 3), 3DGS sign convention;
    a numpy array in, a numpy array out, a tensor in, a tensor out."""
    x, y, z = dirs[..., 0], dirs[..., 1], dirs[..., 2]
    if isinstance(dirs, np.ndarray):
        terms = [np.full_like(x, C0)]
    else:
        import torch

        terms = [torch.full_like(x, C0)]
    if degree > 0:
        terms += [-C1 * y, C1 * z, -C1 * x]
    if degree > 1:
        xx, yy, zz = x * x, y * y, z * z
        terms += [
            C2[0] * x * y,
            C2[1] * y * z,
            C2[2] * (2.0 * zz - xx - yy),
            C2[3] * x * z,
            C2[4] * (xx - yy),
        ]
    if degree > 2:
        terms += [
            C3[0] * y * (3.0 * xx - yy),
            C3[1] * x * y * z,
            C3[2] * y * (4.0 * zz - xx - yy),
            C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy),
            C3[4] * x * (4.0 * zz - xx - yy),
            C3[5] * z * (xx - yy),
            C3[6] * x * (xx - 3.0 * yy),
        ]
    if isinstance(dirs, np.ndarray):
        return np.stack(terms, axis=-1)
    return torch.stack(terms, dim=-1)
