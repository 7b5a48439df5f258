"""Independent reference formulas for the fusion tests (here and in tests/core/stages).

Written unlike the implementation on purpose, so a shared mistake is unlikely: visibility projects
homogeneous points through the 3x4 matrix `K [R | t]` in numpy, where the implementation
normalises camera coordinates in torch.
"""

from __future__ import annotations

import numpy as np


def reference_associations(
    means, K, w2c, width, height, depth, labels, tolerance=0.05, relative=0.03, near=1e-3
) -> set[tuple[int, int]]:
    """(Gaussian, mask) pairs by the 3x4 homogeneous projection: pixel = floor(P X / (P X)_z)."""
    P = K @ w2c[:3]
    X = np.c_[means.astype(np.float64), np.ones(len(means))]
    proj = X @ P.T
    z = X @ w2c[2]
    with np.errstate(divide="ignore", invalid="ignore"):
        x, y = proj[:, 0] / proj[:, 2], proj[:, 1] / proj[:, 2]
    ok = (z > near) & (x >= 0) & (x < width) & (y >= 0) & (y < height)
    ids = np.flatnonzero(ok)
    row, col = np.floor(y[ids]).astype(int), np.floor(x[ids]).astype(int)
    d, lab = depth[row, col].astype(np.float64), labels[row, col]
    hit = (lab >= 0) & (d > 0) & (np.abs(z[ids] - d) <= tolerance + relative * d)
    return set(zip(ids[hit].tolist(), lab[hit].tolist(), strict=True))
