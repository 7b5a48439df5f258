"""The torch (CUDA-path) fusion ops, run on the CPU device, against the numpy CPU path.

A worker with a GPU runs exactly these functions on `cuda`; the arithmetic is the same on every
device (float64 projection, float32 log-odds), so agreement on `cpu` checks the logic.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from bayesian_fields_core.errors import InvariantError
from bayesian_fields_core.fusion.bayes import bayes_update, init_logodds
from bayesian_fields_core.fusion.bayes_torch import bayes_update_torch, init_logodds_torch
from bayesian_fields_core.fusion.visibility import mask_associations
from bayesian_fields_core.fusion.visibility_torch import mask_associations_torch


def _frame(seed: int, n: int = 50_000, width: int = 160, height: int = 120):
    """A random cloud in front of and behind a camera, a depth image that some centres match."""
    rng = np.random.default_rng(seed)
    means = np.c_[rng.uniform(-4, 4, n), rng.uniform(-3, 3, n), rng.uniform(-2, 6, n)].astype(np.float32)
    yaw = rng.uniform(-0.3, 0.3)
    w2c = np.eye(4)
    w2c[:3, :3] = [[np.cos(yaw), 0, np.sin(yaw)], [0, 1, 0], [-np.sin(yaw), 0, np.cos(yaw)]]
    w2c[:3, 3] = rng.normal(0, 0.1, 3)
    K = np.array([[120.0, 0.3, width / 2 + 3], [0.0, 118.0, height / 2 - 2], [0.0, 0.0, 1.0]])
    # Depth = the z of some Gaussian that lands in each pixel (so exact surface hits exist), else
    # random; zeros where nothing is rendered; labels from 12 blobs and -1 gaps.
    cam = w2c[:3, :3] @ means.T.astype(np.float64) + w2c[:3, 3:4]
    z = cam[2]
    front = z > 1e-3
    u = K[0, 0] * cam[0] / z + K[0, 1] * cam[1] / z + K[0, 2]
    v = K[1, 1] * cam[1] / z + K[1, 2]
    inside = front & (u >= 0) & (u < width) & (v >= 0) & (v < height)
    depth = rng.uniform(0.5, 6.0, (height, width)).astype(np.float32)
    depth[v[inside].astype(int), u[inside].astype(int)] = z[inside]
    depth[rng.random((height, width)) < 0.1] = 0.0
    labels = rng.integers(-1, 12, (height, width)).astype(np.int32)
    return means, K, w2c, width, height, depth, labels


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_associations_torch_equal_numpy(seed: int) -> None:
    means, K, w2c, width, height, depth, labels = _frame(seed)
    ref_g, ref_m = mask_associations(means, K, w2c, width, height, depth, labels)
    g, m = mask_associations_torch(
        torch.as_tensor(means), K, w2c, width, height, torch.as_tensor(depth), torch.as_tensor(labels)
    )
    assert g.dtype == torch.int64 and m.dtype == torch.int32
    assert len(ref_g) > 1000  # many pairs: a meaningful comparison
    np.testing.assert_array_equal(g.numpy(), ref_g)
    np.testing.assert_array_equal(m.numpy(), ref_m)


def test_associations_torch_tolerances_match_numpy() -> None:
    means, K, w2c, width, height, depth, labels = _frame(3)
    for tol, rel in ((0.0, 0.0), (0.2, 0.0), (0.0, 0.1)):
        ref_g, _ = mask_associations(
            means, K, w2c, width, height, depth, labels, depth_tolerance=tol, relative_tolerance=rel
        )
        g, _ = mask_associations_torch(
            torch.as_tensor(means),
            K,
            w2c,
            width,
            height,
            torch.as_tensor(depth),
            torch.as_tensor(labels),
            depth_tolerance=tol,
            relative_tolerance=rel,
        )
        np.testing.assert_array_equal(g.numpy(), ref_g)


def test_associations_torch_refuses_bad_shapes() -> None:
    means, K, w2c, width, height, depth, labels = _frame(4, n=10)
    with pytest.raises(InvariantError, match="visibility.depth"):
        mask_associations_torch(
            torch.as_tensor(means),
            K,
            w2c,
            width,
            height,
            torch.as_tensor(depth[:-1]),
            torch.as_tensor(labels),
        )


def test_bayes_update_torch_equals_numpy_over_frames() -> None:
    rng = np.random.default_rng(7)
    n, t = 20_000, 5
    ref = init_logodds(n, t)
    state = init_logodds_torch(n, t, torch.device("cpu"))
    np.testing.assert_array_equal(state.numpy(), ref)
    for _ in range(20):
        m = int(rng.integers(1, 40))
        gids = np.sort(rng.choice(n, size=3000, replace=False)).astype(np.int64)
        mids = rng.integers(0, m, gids.size).astype(np.int32)
        llr = rng.normal(-0.5, 1.0, (m, t)).astype(np.float32)
        acc_ref = bayes_update(ref, gids, mids, llr)
        acc = bayes_update_torch(state, torch.as_tensor(gids), torch.as_tensor(mids), torch.as_tensor(llr))
        np.testing.assert_array_equal(acc.numpy(), acc_ref)
    assert not acc_ref.all()  # OR-phi rejected some masks
    np.testing.assert_allclose(state.numpy(), ref, rtol=0, atol=1e-5)


def test_bayes_update_torch_without_outlier_rejection_and_bad_ids() -> None:
    state = init_logodds_torch(4, 2, torch.device("cpu"))
    llr = torch.tensor([[-1.0, -2.0]])
    acc = bayes_update_torch(state, torch.tensor([1]), torch.tensor([0]), llr, outlier_rejection=False)
    assert acc.tolist() == [True]
    assert state[1].tolist() == pytest.approx(
        [float(init_logodds(1, 1)[0, 0]) - 1.0, float(init_logodds(1, 1)[0, 0]) - 2.0]
    )
    with pytest.raises(InvariantError, match="fusion.mask_ids"):
        bayes_update_torch(state, torch.tensor([1]), torch.tensor([3]), llr)
