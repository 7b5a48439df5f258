"""minimum_obb and OrientedBox: tightness against known boxes, containment, degenerate sets."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import ConvexHull
from scipy.spatial.transform import Rotation

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.geometry.obb import OrientedBox, minimum_obb


def _points_in_box(rng, extents, rotation, center, n):
    local = (rng.random((n, 3)) - 0.5) * np.asarray(extents)
    return local @ rotation.T + np.asarray(center)


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_recovers_a_rotated_box(seed):
    rng = np.random.default_rng(seed)
    rot = Rotation.random(random_state=seed).as_matrix()
    extents = np.array([2.0, 1.0, 0.3])
    pts = _points_in_box(rng, extents, rot, [1.0, -2.0, 0.5], 20_000)
    box = minimum_obb(pts)
    hull_volume = ConvexHull(pts).volume
    assert box.volume >= hull_volume * (1 - 1e-9)
    assert abs(box.volume / np.prod(extents) - 1.0) < 0.03
    assert box.contains(pts).all()
    np.testing.assert_allclose(np.sort(box.extents)[::-1], extents, rtol=0.02)
    np.testing.assert_allclose(box.center, [1.0, -2.0, 0.5], atol=0.02)
    # the longest axis is recovered up to sign
    assert abs(box.rotation[:, 0] @ rot[:, 0]) > 0.999


def test_beats_pca_and_axis_aligned_boxes_on_a_cube():
    # PCA of a cube is arbitrary, so this exercises the hull-face candidates
    rng = np.random.default_rng(5)
    rot = Rotation.from_euler("xyz", [30, 20, 10], degrees=True).as_matrix()
    pts = _points_in_box(rng, [1, 1, 1], rot, [0, 0, 0], 5000)
    box = minimum_obb(pts)
    assert box.volume < 1.02
    aabb = np.prod(np.ptp(pts, axis=0))
    assert box.volume < 0.7 * aabb


def test_rotation_is_proper_and_axes_sorted():
    rng = np.random.default_rng(7)
    box = minimum_obb(rng.normal(size=(500, 3)) * [1, 3, 2])
    np.testing.assert_allclose(box.rotation.T @ box.rotation, np.eye(3), atol=1e-9)
    assert np.linalg.det(box.rotation) == pytest.approx(1.0)
    assert (np.diff(box.extents) <= 0).all()


def test_coplanar_points_get_the_minimum_rectangle():
    rng = np.random.default_rng(3)
    rot = Rotation.from_euler("zx", [30, 50], degrees=True).as_matrix()
    corners = np.array([[0, 0, 0], [2, 0, 0], [0, 1, 0], [2, 1, 0]], dtype=float)
    inner = np.c_[rng.random((200, 2)) * [2, 1], np.zeros(200)]
    pts = np.vstack([corners, inner]) @ rot.T
    box = minimum_obb(pts, min_thickness=0.01)
    np.testing.assert_allclose(box.extents, [2.0, 1.0, 0.01], atol=1e-9)
    assert box.contains(pts).all()


def test_tiny_sets_use_min_thickness():
    one = minimum_obb(np.array([[1.0, 2.0, 3.0]]), min_thickness=0.05)
    np.testing.assert_allclose(one.extents, [0.05] * 3)
    np.testing.assert_allclose(one.center, [1, 2, 3])
    two = minimum_obb(np.array([[0.0, 0, 0], [3.0, 4.0, 0]]), min_thickness=0.05)
    np.testing.assert_allclose(two.extents, [5.0, 0.05, 0.05])
    np.testing.assert_allclose(two.center, [1.5, 2.0, 0.0])
    three = minimum_obb(np.array([[0.0, 0, 0], [1.0, 0, 0], [0, 1.0, 0]]), min_thickness=0.05)
    assert three.volume == pytest.approx(1.0 * 0.05)  # any side-flush rectangle has area 1


def test_bad_points_are_refused():
    with pytest.raises(InputError):
        minimum_obb(np.zeros((0, 3)))
    with pytest.raises(InputError):
        minimum_obb(np.zeros((4, 2)))
    with pytest.raises(InputError):
        minimum_obb(np.array([[0, 0, np.nan]] * 4))


def test_box_geometry_and_round_trip():
    rot = Rotation.from_euler("z", 90, degrees=True).as_matrix()
    box = OrientedBox([1, 0, 0], rot, [4, 2, 1])
    assert box.volume == pytest.approx(8.0)
    corners = box.corners()
    assert corners.shape == (8, 3)
    # axis 0 (length 4) points along world y after the 90 degree turn
    np.testing.assert_allclose(np.ptp(corners, axis=0), [2, 4, 1], atol=1e-12)
    assert box.contains([1, 1.9, 0.4])
    assert not box.contains([2.1, 0, 0])
    assert box.contains([2.1, 0, 0], tol=0.2)
    np.testing.assert_array_equal(box.contains(np.array([[1, 0, 0], [5, 5, 5]])), [True, False])
    again = OrientedBox.from_dict(box.to_dict())
    np.testing.assert_array_equal(again.rotation, box.rotation)
    np.testing.assert_array_equal(again.extents, box.extents)


def test_malformed_boxes_are_refused():
    with pytest.raises(InputError, match="missing field 'extents'"):
        OrientedBox.from_dict({"center": [0, 0, 0], "rotation": np.eye(3).tolist()})
    with pytest.raises(InputError, match="orthonormal"):
        OrientedBox([0, 0, 0], np.ones((3, 3)), [1, 1, 1])
    with pytest.raises(InputError, match="negative"):
        OrientedBox([0, 0, 0], np.eye(3), [1, -1, 1])
