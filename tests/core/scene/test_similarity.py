"""`Similarity`: parsing, algebra, and the mapping of a whole splat checked against independent
quantities (3D covariances, SH colours, and renders from a camera moved by the same transform)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.geometry.obb import minimum_obb
from bayesian_fields_core.render import GaussianRenderer
from bayesian_fields_core.render.projection import covariance_3d
from bayesian_fields_core.render.sh import sh_to_rgb
from bayesian_fields_core.scene.similarity import Similarity

from .conftest import look_at_frame, random_gaussians


def _sim(seed: int = 4, scale: float = 0.37) -> Similarity:
    rot = Rotation.random(random_state=seed).as_matrix()
    return Similarity(scale, rot, np.array([0.4, -1.2, 2.5]))


def test_from_matrix_validates_and_round_trips() -> None:
    sim = _sim()
    back = Similarity.from_matrix(sim.matrix, source="t")
    np.testing.assert_allclose(back.matrix, sim.matrix, atol=1e-12)
    np.testing.assert_allclose(
        Similarity.from_matrix(sim.matrix[:3], source="t").matrix, sim.matrix, atol=1e-12
    )
    np.testing.assert_allclose(sim.then(sim.inverse()).matrix, np.eye(4), atol=1e-12)
    x = np.random.default_rng(0).normal(size=(5, 3))
    np.testing.assert_allclose(sim.points(x), x @ sim.matrix[:3, :3].T + sim.matrix[:3, 3])
    bad = np.diag([1.0, 2.0, 1.0, 1.0])
    with pytest.raises(InputError, match="t: transform is not a similarity"):
        Similarity.from_matrix(bad, source="t")
    with pytest.raises(InputError, match="reflection"):
        Similarity.from_matrix(np.diag([1.0, 1.0, -1.0, 1.0]), source="t")
    with pytest.raises(InputError, match="4x4"):
        Similarity.from_matrix([[1, 2], [3, 4]], source="t")
    with pytest.raises(InputError, match="last row"):
        Similarity.from_matrix(np.ones((4, 4)), source="t")


def test_gaussians_covariances_and_colours_follow_the_transform() -> None:
    """Covariances must become s^2 R Sigma R^T and the colour seen along a direction d in the old
    frame must be the colour seen along R d in the new one (SH bands 1..3 rotated)."""
    g = random_gaussians(200, 3)
    sim = _sim()
    out = sim.gaussians(g)
    np.testing.assert_allclose(out.means, sim.points(g.means), atol=1e-5)
    cov = covariance_3d(torch.from_numpy(g.log_scales).double(), torch.from_numpy(g.quats).double()).numpy()
    cov_out = covariance_3d(
        torch.from_numpy(out.log_scales).double(), torch.from_numpy(out.quats).double()
    ).numpy()
    r = sim.rotation
    expected = sim.scale**2 * r @ cov @ r.T
    per_matrix = np.abs(expected).max(axis=(1, 2), keepdims=True)  # float32 storage: relative to each
    assert (np.abs(cov_out - expected) / per_matrix).max() < 1e-5
    np.testing.assert_array_equal(out.opacity_logits, g.opacity_logits)
    np.testing.assert_array_equal(out.sh[:, 0], g.sh[:, 0])
    eye = np.array([3.0, -2.0, 1.0])
    before = sh_to_rgb(
        torch.from_numpy(g.sh).double(), torch.from_numpy(g.means).double(), torch.from_numpy(eye)
    )
    after = sh_to_rgb(
        torch.from_numpy(out.sh).double(),
        torch.from_numpy(out.means).double(),
        torch.from_numpy(sim.points(eye)),
    )
    np.testing.assert_allclose(after.numpy(), before.numpy(), atol=1e-4)
    back = sim.inverse().gaussians(out)
    np.testing.assert_allclose(back.means, g.means, atol=1e-5)
    np.testing.assert_allclose(back.sh, g.sh, atol=1e-4)


def test_render_of_moved_splat_from_moved_camera_is_unchanged() -> None:
    g = random_gaussians(300, 2, extra=False)
    g.log_scales[:] = np.log(0.05)
    g.means[:] = g.means * 0.3 + np.array([0.3, -0.2, 1.0])
    frame = look_at_frame("f.png", [2.0, 0.5, 1.5], 60.0, 60.0, 32.0, 24.0, 64, 48)
    sim = _sim(scale=2.5)
    w2c = frame.world_to_camera.copy()
    # The camera moved into the new frame: its rigid pose composed with the inverse similarity,
    # depths in the new frame being `scale` times the old ones.
    moved = np.eye(4)
    inv = sim.inverse()
    moved[:3, :3] = w2c[:3, :3] @ inv.rotation
    moved[:3, 3] = sim.scale * (w2c[:3, :3] @ inv.translation + w2c[:3, 3])
    a = GaussianRenderer(g).render(frame.K, w2c, 64, 48)
    b = GaussianRenderer(sim.gaussians(g)).render(frame.K, moved, 64, 48)
    np.testing.assert_allclose(b.rgb, a.rgb, atol=2e-3)
    np.testing.assert_allclose(b.depth, a.depth * sim.scale, rtol=1e-3, atol=1e-4)


def test_boxes_map_to_boxes() -> None:
    pts = np.random.default_rng(2).normal(size=(100, 3)) * [1.0, 0.5, 0.2]
    sim = _sim()
    box = sim.box(minimum_obb(pts))
    grown = type(box)(box.center, box.rotation, box.extents + 1e-6)
    assert grown.contains(sim.points(pts)).all()
