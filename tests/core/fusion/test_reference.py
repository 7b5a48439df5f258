"""The fusion ops (the one implementation a CPU run and a GPU worker both execute) against
independent formulas, on the CPU and, where this machine has one, on a CUDA device.

The references are written differently on purpose: visibility projects homogeneous points with
the 3x4 matrix `K [R | t]` in numpy instead of normalising camera coordinates; the update, the
peaks, the view counts and the averaging sums are dense (N, T) numpy arrays built frame by frame
from explicit loops over the masks. Equality is exact wherever the arithmetic allows it (the
log-odds get exactly one float32 add per element and frame, so the dense sum is the same number).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.special import logit

from bayesian_fields_core.errors import InvariantError
from bayesian_fields_core.fusion.averaging import CosineAverager
from bayesian_fields_core.fusion.bayes import bayes_update, count_views, init_logodds
from bayesian_fields_core.fusion.peak import UNSEEN, init_peak, update_peak
from bayesian_fields_core.fusion.visibility import centre_columns, mask_associations

from .reference import reference_associations

DEVICES = [
    "cpu",
    pytest.param("cuda", marks=pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")),
]


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


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_associations_equal_the_homogeneous_projection(seed: int, device: str) -> None:
    means, K, w2c, width, height, depth, labels = _frame(seed)
    g, m = mask_associations(
        centre_columns(means, device),
        K,
        w2c,
        width,
        height,
        torch.as_tensor(depth, device=device),  # a rendered depth arrives as a tensor on the device
        labels,  # a label image as a host array
        depth_tolerance=0.05,
    )
    assert g.device.type == device and g.dtype == torch.int64 and m.dtype == torch.int32
    g, m = g.cpu().numpy(), m.cpu().numpy()
    assert np.all(np.diff(g) > 0)  # ids ascending, each Gaussian once
    expected = reference_associations(means, K, w2c, width, height, depth, labels)
    assert len(expected) > 1000  # many pairs: a meaningful comparison
    assert set(zip(g.tolist(), m.tolist(), strict=True)) == expected


@pytest.mark.parametrize("tolerance, relative", [(0.2, 0.0), (0.0, 0.1), (0.05, 0.03)])
def test_associations_tolerances_equal_the_reference(tolerance: float, relative: float) -> None:
    means, K, w2c, width, height, depth, labels = _frame(3)
    g, m = mask_associations(
        centre_columns(means, "cpu"),
        K,
        w2c,
        width,
        height,
        depth,
        labels,
        depth_tolerance=tolerance,
        relative_tolerance=relative,
    )
    expected = reference_associations(means, K, w2c, width, height, depth, labels, tolerance, relative)
    assert len(expected) > 100
    assert set(zip(g.tolist(), m.tolist(), strict=True)) == expected


def test_associations_refuse_bad_shapes() -> None:
    means, K, w2c, width, height, depth, labels = _frame(4, n=10)
    centres = centre_columns(means, "cpu")
    with pytest.raises(InvariantError, match="visibility.depth"):
        mask_associations(centres, K, w2c, width, height, depth[:-1], labels, depth_tolerance=0.05)
    with pytest.raises(InvariantError, match="visibility.centres"):
        mask_associations(torch.as_tensor(means), K, w2c, width, height, depth, labels, depth_tolerance=0.05)
    with pytest.raises(InvariantError, match="visibility.means"):
        centre_columns(means[:, :2], "cpu")


def _frames(n: int, t: int, count: int, seed: int = 7):
    """Random frames: (gaussian_ids int64 (k,), mask_ids int32 (k,), llr (M, T), margins (M, T)),
    each Gaussian at most once per frame as exclusive masks make it."""
    rng = np.random.default_rng(seed)
    for _ in range(count):
        masks = int(rng.integers(1, 40))
        gids = np.sort(rng.choice(n, size=3000, replace=False)).astype(np.int64)
        mids = rng.integers(0, masks, gids.size).astype(np.int32)
        llr = rng.normal(-0.5, 1.0, (masks, t)).astype(np.float32)
        yield gids, mids, llr, rng.normal(0.5, 1.0, (masks, t)).astype(np.float32)


def _accepted(llr: np.ndarray) -> np.ndarray:
    """OR-phi by its definition: keep a mask when some task's ratio is >= 1 (llr >= 0)."""
    return np.array([any(value >= 0 for value in row) for row in llr.tolist()], dtype=bool)


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.slow
def test_update_peak_and_view_counts_equal_dense_references(device: str) -> None:
    n, t = 20_000, 5
    state = init_logodds(n, t, device=device)
    peak = init_peak(n, t, device)
    views = torch.zeros(n, dtype=torch.int32, device=device)
    ref = np.full((n, t), np.float32(logit(0.05)), dtype=np.float32)
    ref_peak = np.full((n, t), UNSEEN, dtype=np.float32)
    ref_views = np.zeros(n, dtype=np.int32)
    rejected = 0
    for gids, mids, llr, margins in _frames(n, t, 20):
        flags = _accepted(llr)
        rejected += int((~flags).sum())
        g, m = torch.as_tensor(gids, device=device), torch.as_tensor(mids, device=device)
        accepted = bayes_update(state, g, m, torch.as_tensor(llr, device=device))
        assert accepted.device.type == device
        np.testing.assert_array_equal(accepted.cpu().numpy(), flags)
        update_peak(peak, g, m, margins, accepted)
        count_views(views, g, m, accepted)
        increment = np.zeros((n, t), dtype=np.float32)  # 0 elsewhere: x + 0 is x exactly
        for k in range(len(gids)):
            if flags[mids[k]]:
                increment[gids[k]] = llr[mids[k]]
                ref_peak[gids[k]] = np.maximum(ref_peak[gids[k]], margins[mids[k]])
                ref_views[gids[k]] += 1
        ref += increment
    assert rejected > 0  # OR-phi had something to reject
    np.testing.assert_array_equal(state.cpu().numpy(), ref)
    np.testing.assert_array_equal(peak.cpu().numpy(), ref_peak)
    np.testing.assert_array_equal(views.cpu().numpy(), ref_views)


def test_bayes_update_without_outlier_rejection_and_bad_ids() -> None:
    state = init_logodds(4, 2)
    start = float(state[0, 0])
    llr = torch.tensor([[-1.0, -2.0]])
    acc = bayes_update(state, torch.tensor([1]), torch.tensor([0]), llr, outlier_rejection=False)
    assert acc.tolist() == [True]
    assert state[1].tolist() == pytest.approx([start - 1.0, start - 2.0])
    with pytest.raises(InvariantError, match="fusion.mask_ids"):
        bayes_update(state, torch.tensor([1]), torch.tensor([3]), llr)


@pytest.mark.parametrize("device", DEVICES)
def test_averaging_sums_equal_a_dense_float64_reference(device: str) -> None:
    n, t = 5_000, 3
    avg = CosineAverager(n, t, device)
    sums, counts = np.zeros((n, t)), np.zeros(n, dtype=np.int64)
    for gids, mids, llr, phi in _frames(n, t, 12, seed=11):
        flags = _accepted(llr)
        avg.add_frame(gids, mids, phi, flags)
        for k in range(len(gids)):
            if flags[mids[k]]:
                sums[gids[k]] += phi[mids[k]].astype(np.float64)
                counts[gids[k]] += 1
    host_sums, host_counts = avg.host_state()
    np.testing.assert_array_equal(host_sums, sums)
    np.testing.assert_array_equal(host_counts, counts)
    assert (counts > 1).any() and (counts == 0).any()
