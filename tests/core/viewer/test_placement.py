"""The viewer's start view and label placement, on the sample's real cameras and splat (no browser:
plain geometry, checked by projecting back through the camera)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from bayesian_fields_core.scene.loader import load_scene
from bayesian_fields_core.scene.types import Frame, Scene
from bayesian_fields_core.viewer.placement import (
    LABEL_CHAR_WIDTH,
    LABEL_HEIGHT,
    box_top,
    label_anchors,
    label_text,
    start_view,
)

SAMPLE = Path(__file__).resolve().parents[3] / "samples" / "tabletop"


@pytest.fixture(scope="module")
def scene() -> Scene:
    return load_scene(SAMPLE)


def project(frame: Frame, point: np.ndarray) -> tuple[float, float, float]:
    cam = frame.world_to_camera[:3, :3] @ point + frame.world_to_camera[:3, 3]
    return (
        frame.K[0, 0] * cam[0] / cam[2] + frame.K[0, 2],
        frame.K[1, 1] * cam[1] / cam[2] + frame.K[1, 2],
        cam[2],
    )


def test_the_view_starts_at_the_first_training_camera(scene: Scene) -> None:
    first = scene.frames[0]
    view = start_view(first, scene.gaussians.means)
    np.testing.assert_allclose(view.position, first.camera_centre, atol=1e-9)
    # the pivot is on the optical axis: it projects onto the principal point, in front
    u, v, depth = project(first, np.asarray(view.look_at))
    assert u == pytest.approx(first.K[0, 2]) and v == pytest.approx(first.K[1, 2]) and depth > 0
    depths = np.array([project(first, p)[2] for p in scene.gaussians.means[::50]])
    assert np.quantile(depths[depths > 0], 0.25) < depth < np.quantile(depths[depths > 0], 0.75)
    # up is the photo's up (OpenCV -y), the fov the lens's (transforms.json: fl_y and h)
    np.testing.assert_allclose(view.up, -first.camera_to_world[:3, 1], atol=1e-9)
    doc = json.loads((SAMPLE / "transforms.json").read_text())["frames"][0]
    assert view.fov == pytest.approx(2 * np.arctan(doc["h"] / (2 * doc["fl_y"])))


def test_a_box_top_is_its_highest_corner() -> None:
    up = np.array([0.0, 0.0, 1.0])
    assert box_top(np.zeros(3), np.eye(3), np.array([2.0, 4.0, 6.0]), up).tolist() == [1.0, 2.0, 3.0]
    c, s = np.cos(np.pi / 4), np.sin(np.pi / 4)
    tilted = np.array([[1.0, 0, 0], [0, c, -s], [0, s, c]])  # 45 degrees about x
    top = box_top(np.zeros(3), tilted, np.array([2.0, 2.0, 2.0]), up)
    corners = [tilted @ np.array([x, y, z]) for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]
    assert top[2] == pytest.approx(max(p[2] for p in corners))


def _rect(frame: Frame, anchor: np.ndarray, text: str) -> tuple[float, float, float, float]:
    u, v, _ = project(frame, anchor)
    return u, u + len(text) * LABEL_CHAR_WIDTH * frame.height, v - LABEL_HEIGHT * frame.height, v


def test_labels_of_nearby_boxes_are_stacked_apart_in_the_start_view(scene: Scene) -> None:
    first = scene.frames[0]
    look_at = np.asarray(start_view(first, scene.gaussians.means).look_at)
    right = first.camera_to_world[:3, 0]
    # five boxes whose tops almost coincide on screen (the sample's table objects seen from afar)
    tops = np.stack([look_at + 0.002 * k * right for k in range(5)])
    texts = [label_text(k, 0.9 - 0.1 * k) for k in range(5)]
    anchors = label_anchors(tops, texts, first)
    np.testing.assert_allclose(anchors[0], tops[0])  # the top-ranked label stays on its box
    rects = [_rect(first, a, t) for a, t in zip(anchors, texts, strict=True)]
    for i in range(5):
        for j in range(i):
            a, b = rects[i], rects[j]
            overlap = a[0] < b[1] and b[0] < a[1] and a[2] < b[3] and b[2] < a[3]
            assert not overlap, (i, j, a, b)
    # each is moved straight up the photo (along the camera's up axis), not sideways or in depth
    for top, anchor in zip(tops, anchors, strict=True):
        np.testing.assert_allclose(np.cross(anchor - top, first.camera_to_world[:3, 1]), 0, atol=1e-9)


def test_labels_of_boxes_apart_stay_on_their_boxes(scene: Scene) -> None:
    first = scene.frames[0]
    look_at = np.asarray(start_view(first, scene.gaussians.means).look_at)
    right = first.camera_to_world[:3, 0]
    tops = np.stack([look_at - 0.3 * right, look_at + 0.3 * right])
    np.testing.assert_allclose(label_anchors(tops, ["#1 0.99", "#2 0.97"], first), tops)


def test_label_text_is_short() -> None:
    assert label_text(0, 0.9751) == "#1 0.98"
