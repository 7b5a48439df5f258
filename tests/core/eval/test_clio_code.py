"""The Clio-code scoring against hand-made boxes, one test per rule of Clio's evaluation code."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.eval.clio import EstimatedObject, GTObject, clio_metrics
from bayesian_fields_core.eval.clio_code import clio_code_contains, clio_code_metrics, scene_mean
from bayesian_fields_core.eval.suite import pool_scores
from bayesian_fields_core.geometry.obb import OrientedBox

_I = np.eye(3)


def _box(center: tuple[float, float, float], size: float, rotation: np.ndarray = _I) -> OrientedBox:
    return OrientedBox(np.array(center, float), rotation, np.full(3, size))


def _one(est: OrientedBox, gt: OrientedBox) -> tuple[list[EstimatedObject], list[GTObject]]:
    return [EstimatedObject(est, {"t": 1.0})], [GTObject("t", gt)]


def test_containment_is_twice_the_extent_with_the_boundary_inside() -> None:
    unit = _box((0, 0, 0), 1.0)  # the real box reaches 0.5 from its centre
    assert not unit.contains(np.array([0.9, 0.0, 0.0]), 1e-9)
    assert clio_code_contains(unit, _box((0.9, 0, 0), 0.1))
    assert clio_code_contains(unit, _box((1.0, -1.0, 1.0), 0.1))  # on the doubled boundary
    assert not clio_code_contains(unit, _box((1.01, 0, 0), 0.1))


def test_rotation_is_ignored() -> None:
    turned = Rotation.from_euler("z", 45, degrees=True).as_matrix()
    slab = OrientedBox(np.zeros(3), turned, np.array([1.0, 0.1, 0.1]))
    point = _box((0.9, 0.05, 0.0), 0.1)  # outside the turned slab, inside its unturned double
    assert not slab.contains(point.center, 1e-9)
    assert clio_code_contains(slab, point)
    unturned = OrientedBox(np.zeros(3), _I, slab.extents)
    for x in np.linspace(-1.2, 1.2, 13):
        probe = _box((x, 0.09, 0.05), 0.1)
        assert clio_code_contains(slab, probe) == clio_code_contains(unturned, probe)


def test_relaxed_needs_the_gt_centre_inside_the_estimate() -> None:
    # The estimate sits inside the GT box's edge: the GT holds its centre, it does not hold the GT's.
    est, gt = _one(_box((0.45, 0, 0), 0.2), _box((0, 0, 0), 1.0))
    geometric = clio_metrics(est, gt)  # the paper's written "either" rule
    code = clio_code_metrics(est, gt)
    assert (geometric.relaxed_osr, geometric.strict_osr) == (1.0, 0.0)
    assert (code.relaxed_osr, code.strict_osr) == (0.0, 0.0)
    assert code.iou == pytest.approx(geometric.iou) and code.iou > 0
    # The other way round (the estimate holds the GT centre, not vice versa) is Relaxed in both.
    big_est, small_gt = _one(_box((0, 0, 0), 1.0), _box((0.45, 0, 0), 0.2))
    assert clio_code_metrics(big_est, small_gt).relaxed_osr == 1.0


def test_strict_is_looser_by_the_doubled_boxes() -> None:
    # Centres 0.7 apart, boxes of side 1: neither real box holds the other's centre.
    est, gt = _one(_box((0.7, 0, 0), 1.0), _box((0, 0, 0), 1.0))
    geometric = clio_metrics(est, gt)
    code = clio_code_metrics(est, gt)
    assert (geometric.strict_osr, geometric.relaxed_osr) == (0.0, 0.0)
    assert (code.strict_osr, code.relaxed_osr) == (1.0, 1.0)
    assert code.iou == pytest.approx(geometric.iou) == pytest.approx(0.3 / 1.7)


def test_scenes_are_averaged_not_pooled() -> None:
    hit = clio_code_metrics(*_one(_box((0, 0, 0), 1.0), _box((0, 0, 0), 1.0)))
    far = [EstimatedObject(_box((10 + i, 0, 0), 0.5), {"t": 1.0}) for i in range(3)]
    misses = clio_code_metrics(far, [GTObject("t", _box((0, float(i), 0), 0.5)) for i in range(3)])
    assert (hit.strict_osr, misses.strict_osr) == (1.0, 0.0)
    assert scene_mean([hit, misses]).strict_osr == pytest.approx(0.5)  # Clio's code: per scene
    assert pool_scores([hit, misses]).strict_osr == pytest.approx(0.25)  # the project: 1 of 4 pairs
    with pytest.raises(InputError, match="no scenes"):
        scene_mean([])
