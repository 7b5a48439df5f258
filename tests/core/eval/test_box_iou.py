"""Exact oriented-box IoU against hand-computed volumes."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bayesian_fields_core.eval.box_iou import (
    obb_contains_centroid,
    obb_intersection_volume,
    obb_iou,
    obb_iou_matrix,
)
from bayesian_fields_core.geometry.obb import OrientedBox

EYE = np.eye(3)


def test_identical_boxes():
    rot = Rotation.from_euler("xyz", [10, 20, 30], degrees=True).as_matrix()
    box = OrientedBox([1, 2, 3], rot, [1, 2, 3])
    assert obb_iou(box, box) == pytest.approx(1.0, abs=1e-9)


def test_disjoint_and_touching_boxes():
    a = OrientedBox([0, 0, 0], EYE, [2, 2, 2])
    assert obb_iou(a, OrientedBox([10, 0, 0], EYE, [2, 2, 2])) == 0.0
    # bounding spheres overlap, boxes do not
    assert obb_iou(a, OrientedBox([2.5, 2.5, 0], EYE, [2, 2, 2])) == 0.0
    # sharing a face: zero-volume intersection
    assert obb_iou(a, OrientedBox([2, 0, 0], EYE, [2, 2, 2])) == 0.0


@pytest.mark.parametrize(
    ("center_b", "extents_b", "intersection"),
    [
        ([1, 0, 0], [2, 2, 2], 1 * 2 * 2),  # half overlap along x
        ([1, 1, 0], [2, 2, 2], 1 * 1 * 2),  # quarter
        ([1, 1, 1], [2, 2, 2], 1.0),  # one octant
        ([0, 0, 0], [1, 1, 1], 1.0),  # nested
        ([0.5, 0, 0], [3, 1, 0.5], 2 * 1 * 0.5),  # x in [-1, 2] pokes out of one face
    ],
)
def test_axis_aligned_overlaps(center_b, extents_b, intersection):
    a = OrientedBox([0, 0, 0], EYE, [2, 2, 2])
    b = OrientedBox(center_b, EYE, extents_b)
    assert obb_intersection_volume(a, b) == pytest.approx(intersection, rel=1e-9)
    expected = intersection / (8 + np.prod(extents_b) - intersection)
    assert obb_iou(a, b) == pytest.approx(expected, rel=1e-9)
    assert obb_iou(b, a) == pytest.approx(expected, rel=1e-9)


def test_rotated_square_prism_octagon():
    # square [-1,1]^2 vs the same square turned 45 degrees: the overlap is a regular octagon,
    # the square minus 4 corner triangles with legs 2 - sqrt(2): area 4 - 2(2 - sqrt2)^2 = 8 sqrt2 - 8
    a = OrientedBox([0, 0, 0], EYE, [2, 2, 2])
    b = OrientedBox([0, 0, 0], Rotation.from_euler("z", 45, degrees=True).as_matrix(), [2, 2, 2])
    inter = (8 * np.sqrt(2) - 8) * 2
    assert obb_intersection_volume(a, b) == pytest.approx(inter, rel=1e-9)
    assert obb_iou(a, b) == pytest.approx(inter / (16 - inter), rel=1e-9)


@pytest.mark.slow
def test_rotated_box_matches_monte_carlo():
    rng = np.random.default_rng(0)
    a = OrientedBox([0, 0, 0], Rotation.from_euler("xyz", [20, 40, 10], degrees=True).as_matrix(), [2, 1, 1])
    b = OrientedBox([0.4, 0.2, 0], Rotation.from_euler("y", 70, degrees=True).as_matrix(), [1.5, 1, 0.8])
    pts = rng.random((400_000, 3)) * 4 - 2
    mc = (a.contains(pts) & b.contains(pts)).mean() * 64
    assert obb_intersection_volume(a, b) == pytest.approx(mc, rel=0.02)


def test_iou_matrix_and_centroids():
    a = OrientedBox([0, 0, 0], EYE, [2, 2, 2])
    b = OrientedBox([0.75, 0, 0], EYE, [1, 1, 1])  # x in [0.25, 1.25]: 0.75 of it inside a
    c = OrientedBox([3, 0, 0], EYE, [0.2, 0.2, 0.2])
    m = obb_iou_matrix([a, b], [a, b, c])
    assert m.shape == (2, 3)
    assert m[0, 0] == pytest.approx(1.0)
    assert m[0, 1] == pytest.approx(0.75 / (8 + 1 - 0.75))
    assert m[1, 2] == 0.0
    assert obb_contains_centroid(a, b)
    assert not obb_contains_centroid(b, a)
