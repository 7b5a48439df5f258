"""Projection, occlusion and label lookup of `mask_associations` on a hand-placed scene."""

import numpy as np
import pytest
import torch

from bayesian_fields_core.errors import InvariantError
from bayesian_fields_core.fusion.visibility import centre_columns, mask_associations

TOL = 0.05
"""Absolute depth tolerance (scene units; the pipeline passes a fraction of the scene scale)."""
K = np.array([[10.0, 0.0, 4.0], [0.0, 10.0, 3.0], [0.0, 0.0, 1.0]])
W, H = 8, 6


def _scene() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    means = np.array(
        [
            [0.0, 0.0, 2.0],  # 0: pixel (3, 4), depth 2 there -> visible, label 1
            [0.0, 0.0, 3.0],  # 1: same pixel, 1 m behind the surface -> occluded
            [0.2, 0.0, 2.0],  # 2: pixel (3, 5), unlabelled -> no pair
            [0.0, 0.0, -2.0],  # 3: behind the camera
            [10.0, 0.0, 2.0],  # 4: outside the image
            [-0.3, -0.2, 1.0],  # 5: pixel (1, 1), nothing rendered (depth 0)
            [0.1, 0.1, 1.0],  # 6: pixel (4, 5), rendered depth 1.02 -> visible, label 0
        ],
        dtype=np.float32,
    )
    depth = np.zeros((H, W), dtype=np.float32)
    labels = np.full((H, W), -1, dtype=np.int32)
    depth[3, 4], labels[3, 4] = 2.0, 1
    depth[3, 5] = 2.0
    depth[4, 5], labels[4, 5] = 1.02, 0
    labels[1, 1] = 2
    return means, depth, labels


def test_visibility_with_occlusion() -> None:
    means, depth, labels = _scene()
    gids, mids = mask_associations(
        centre_columns(means, "cpu"), K, np.eye(4), W, H, depth, labels, depth_tolerance=TOL
    )
    assert gids.dtype == torch.int64 and mids.dtype == torch.int32
    assert gids.tolist() == [0, 6]
    assert mids.tolist() == [1, 0]


def test_relative_tolerance_grows_with_depth() -> None:
    # Gaussian at z = 4.1 in front of a pixel rendered at 4.0: tol = 0.02 + 0.03 * 4 = 0.14 passes;
    # with the relative term off, 0.1 > 0.02 fails.
    means = np.array([[0.0, 0.0, 4.1]], dtype=np.float32)
    depth = np.zeros((H, W), dtype=np.float32)
    labels = np.full((H, W), -1, dtype=np.int32)
    depth[3, 4], labels[3, 4] = 4.0, 7
    gids, mids = mask_associations(
        centre_columns(means, "cpu"), K, np.eye(4), W, H, depth, labels, depth_tolerance=TOL
    )
    assert gids.tolist() == [0] and mids.tolist() == [7]
    gids, _ = mask_associations(
        centre_columns(means, "cpu"),
        K,
        np.eye(4),
        W,
        H,
        depth,
        labels,
        depth_tolerance=TOL,
        relative_tolerance=0.0,
    )
    assert gids.numel() == 0


def test_world_to_camera_is_applied() -> None:
    means, depth, labels = _scene()
    # Camera moved 1 unit back along z: world z = 1 is camera z = 2 (Gaussian 0's pixel and depth).
    w2c = np.eye(4)
    w2c[2, 3] = 1.0
    shifted = means[:1] - np.array([0.0, 0.0, 1.0], dtype=np.float32)
    gids, mids = mask_associations(
        centre_columns(shifted, "cpu"), K, w2c, W, H, depth, labels, depth_tolerance=TOL
    )
    assert gids.tolist() == [0] and mids.tolist() == [1]


def test_bad_image_shape_raises() -> None:
    means, depth, labels = _scene()
    with pytest.raises(InvariantError, match="visibility.labels"):
        mask_associations(
            centre_columns(means, "cpu"), K, np.eye(4), W, H, depth, labels[:, :-1], depth_tolerance=TOL
        )
