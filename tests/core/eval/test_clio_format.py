"""Clio's dataset files: task YAML (quaternion boxes) and scene_transforms.yaml, validated, and
mapped so the metrics do not depend on which frame the ground truth was written in."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.eval.clio import ClioScores, EstimatedObject, GTObject, clio_metrics
from bayesian_fields_core.eval.clio_format import (
    load_clio_case,
    parse_clio_ground_truth,
    parse_scene_transform,
    quaternion_matrix,
    read_clio_ground_truth,
)
from bayesian_fields_core.geometry.obb import OrientedBox
from bayesian_fields_core.scene.similarity import Similarity

# Clio's cubicle entry of clio_eval/scene_transforms.yaml (a rigid T and a scale).
CUBICLE_T = [
    [0.8680003, 0.34739165, -0.35481618, -0.06814865],
    [0.42267521, -0.14186624, 0.89510873, 2.0763137],
    [0.26061686, -0.92692665, -0.26997378, -0.30536732],
    [0.0, 0.0, 0.0, 1.0],
]


def clio_box(box: OrientedBox, as_list: bool) -> dict:
    """A box in Clio's YAML form: quaternion w first, as a list or a mapping."""
    x, y, z, w = Rotation.from_matrix(box.rotation).as_quat()
    rot = (
        [float(w), float(x), float(y), float(z)]
        if as_list
        else {"w": float(w), "x": float(x), "y": float(y), "z": float(z)}
    )
    return {"center": box.center.tolist(), "extents": box.extents.tolist(), "rotation": rot}


def assert_same_scores(a: ClioScores, b: ClioScores) -> None:
    """Equal metrics, task by task (IoU sums to rounding)."""
    assert (a.strict_osr, a.relaxed_osr, a.num_gt) == (b.strict_osr, b.relaxed_osr, b.num_gt)
    assert a.iou == pytest.approx(b.iou, abs=1e-9)
    assert a.per_task.keys() == b.per_task.keys()
    for task, ts in a.per_task.items():
        other = b.per_task[task]
        assert (ts.num_gt, ts.strict, ts.relaxed) == (other.num_gt, other.strict, other.relaxed), task
        assert ts.iou_sum == pytest.approx(other.iou_sum, abs=1e-9), task


def test_quaternions_in_both_forms_match_scipy() -> None:
    rot = Rotation.from_euler("zyx", [30, -20, 75], degrees=True)
    x, y, z, w = rot.as_quat()
    np.testing.assert_allclose(quaternion_matrix([w, x, y, z]), rot.as_matrix(), atol=1e-12)
    np.testing.assert_allclose(
        quaternion_matrix({"x": x, "w": w, "z": z, "y": y}), rot.as_matrix(), atol=1e-12
    )
    # Not unit length: normalised, as scipy does in Clio's code.
    np.testing.assert_allclose(quaternion_matrix([2 * w, 2 * x, 2 * y, 2 * z]), rot.as_matrix(), atol=1e-12)


def test_ground_truth_keeps_task_order_and_absent_tasks() -> None:
    data = {
        "get  the soap": [{"center": [1, 2, 3], "extents": [0.2, 0.1, 0.3], "rotation": [1, 0, 0, 0]}],
        "pick up the red lamp": [],
        "read book": [
            {"center": [0, 0, 0], "extents": [1, 1, 1], "rotation": {"w": 1, "x": 0, "y": 0, "z": 0}},
            {"center": [2, 0, 0], "extents": [1, 1, 1], "rotation": [0, 0, 0, 1]},
        ],
    }
    gt = parse_clio_ground_truth(data, source="tasks.yaml")
    assert gt.tasks == ["get the soap", "pick up the red lamp", "read book"]  # whitespace normalised
    assert [g.task for g in gt.objects] == ["get the soap", "read book", "read book"]
    assert gt.absent_tasks == ["pick up the red lamp"]
    # [0, 0, 0, 1] is w=0, z=1: half a turn about z
    np.testing.assert_allclose(gt.objects[2].box.rotation, np.diag([-1.0, -1.0, 1.0]), atol=1e-12)


@pytest.mark.parametrize(
    ("entry", "message"),
    [
        ({"center": [0, 0, 0], "extents": [1, 1, 1], "rotation": [1, 0, 0]}, "quaternion"),
        ({"center": [0, 0, 0], "extents": [1, 1, 1], "rotation": [[1, 0, 0], [0, 1, 0]]}, "quaternion"),
        (
            {"center": [0, 0, 0], "extents": [1, 1, 1], "rotation": {"w": 1, "x": 0, "y": 0}},
            "keys w, x, y, z",
        ),
        ({"center": [0, 0, 0], "extents": [1, 1, 1], "rotation": [0, 0, 0, 0]}, "zero norm"),
        ({"center": [0, 0, 0], "extents": [1, 1, 1], "rotation": "identity"}, "quaternion"),
        ({"center": [0, 0, float("nan")], "extents": [1, 1, 1], "rotation": [1, 0, 0, 0]}, "finite"),
        ({"center": [0, 0, 0], "extents": [1, float("inf"), 1], "rotation": [1, 0, 0, 0]}, "finite"),
        ({"center": [0, 0, 0], "extents": [1, 1, 1], "rotation": [1, 0, float("nan"), 0]}, "finite"),
        ({"center": [0, 0], "extents": [1, 1, 1], "rotation": [1, 0, 0, 0]}, "center must be a list of 3"),
        ({"center": [0, 0, 0], "extents": [1, 0, 1], "rotation": [1, 0, 0, 0]}, "positive"),
        ({"center": [0, 0, "a"], "extents": [1, 1, 1], "rotation": [1, 0, 0, 0]}, "numbers only"),
        ({"center": [0, 0, 0], "rotation": [1, 0, 0, 0]}, "missing field 'extents'"),
        ([0, 0, 0], "expected a mapping"),
    ],
)
def test_bad_boxes_are_one_line_errors_naming_file_task_and_box(entry: object, message: str) -> None:
    with pytest.raises(InputError, match=message) as err:
        parse_clio_ground_truth(
            {"ok": [{"center": [0, 0, 0], "extents": [1, 1, 1], "rotation": [1, 0, 0, 0]}], "t": [entry]},
            source="gt.yaml",
        )
    text = str(err.value)
    assert text.startswith("gt.yaml: task 't' box 0: ") and "\n" not in text


def test_bad_files(tmp_path: Path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text("get soap: [center: [0, 0\n")
    with pytest.raises(InputError, match="cannot parse YAML") as err:
        read_clio_ground_truth(bad)
    assert str(bad) in str(err.value) and "\n" not in str(err.value)
    with pytest.raises(InputError, match="cannot read"):
        read_clio_ground_truth(tmp_path / "missing.yaml")
    for doc, message in (([1, 2], "mapping"), ({"t": "box"}, "list of boxes"), ({"t": []}, "no task has")):
        with pytest.raises(InputError, match=message):
            parse_clio_ground_truth(doc, source="gt.yaml")


def test_scene_transform_forms_and_errors() -> None:
    one = parse_scene_transform({"T": CUBICLE_T, "scale": 0.3527}, source="t.yaml")
    np.testing.assert_allclose(one.scale, 0.3527)
    np.testing.assert_allclose(one.translation, [-0.06814865, 2.0763137, -0.30536732])
    # Clio's layout: keyed by scene; the key, else the scene folder's name, else the only entry.
    keyed = {"cubicle": {"T": CUBICLE_T, "scale": 0.3527}, "office": {"T": np.eye(4).tolist(), "scale": 2.1}}
    assert parse_scene_transform(keyed, source="t.yaml", key="office").scale == 2.1
    assert parse_scene_transform(keyed, source="t.yaml", default_key="cubicle").scale == 0.3527
    assert parse_scene_transform({"office": keyed["office"]}, source="t.yaml").scale == 2.1
    with pytest.raises(InputError, match="several scenes"):
        parse_scene_transform(keyed, source="t.yaml", default_key="apartment")
    with pytest.raises(InputError, match="no scene 'apartment'"):
        parse_scene_transform(keyed, source="t.yaml", key="apartment")
    shear = np.eye(4)
    shear[0, 1] = 0.3
    scaled = np.eye(4) * 2.0
    scaled[3, 3] = 1.0
    for entry, message in (
        ({"T": CUBICLE_T}, "T \\(4x4\\) and scale"),
        ({"T": CUBICLE_T[:3], "scale": 1.0}, "4x4"),
        ({"T": CUBICLE_T, "scale": 0}, "scale must be"),
        ({"T": CUBICLE_T, "scale": float("nan")}, "scale must be"),
        ({"T": [[float("inf"), 0, 0, 0], *CUBICLE_T[1:]], "scale": 1.0}, "finite"),
        ({"T": shear.tolist(), "scale": 1.0}, "not a similarity"),
        ({"T": scaled.tolist(), "scale": 1.0}, "rigid"),
    ):
        with pytest.raises(InputError, match=message) as err:
            parse_scene_transform(entry, source="t.yaml")
        assert str(err.value).startswith("t.yaml") and "\n" not in str(err.value)


def test_metrics_do_not_depend_on_the_frame_the_gt_was_written_in(tmp_path: Path) -> None:
    """GT written in Clio's frame (x_gt = T(scale x)), read back with the transform file, scores a
    map exactly as the scene-frame GT does."""
    rng = np.random.default_rng(3)
    scene_gt = [
        GTObject(
            task,
            OrientedBox(
                rng.uniform(-1, 1, 3), Rotation.random(random_state=i).as_matrix(), rng.uniform(0.1, 0.5, 3)
            ),
        )
        for i, task in enumerate(["get soap", "get soap", "read book", "water plant"])
    ]
    estimates = [
        EstimatedObject(
            OrientedBox(
                g.box.center + rng.normal(0, 0.05, 3),
                g.box.rotation,
                g.box.extents * rng.uniform(0.8, 1.3, 3),
            ),
            {g.task: 0.9 - 0.1 * i},
        )
        for i, g in enumerate(scene_gt)
    ]
    to_gt = parse_scene_transform({"T": CUBICLE_T, "scale": 0.3527}, source="t")
    doc: dict[str, list] = {"get soap": [], "read book": [], "water plant": [], "find the red lamp": []}
    for i, g in enumerate(scene_gt):
        doc[g.task].append(clio_box(to_gt.box(g.box), as_list=bool(i % 2)))
    (tmp_path / "tasks.yaml").write_text(yaml.safe_dump(doc))
    (tmp_path / "scene_transforms.yaml").write_text(
        yaml.safe_dump(
            {"cubicle": {"T": CUBICLE_T, "scale": 0.3527}, "office": {"T": np.eye(4).tolist(), "scale": 2.1}}
        )
    )
    gt = load_clio_case(tmp_path / "tasks.yaml", tmp_path / "scene_transforms.yaml", default_key="cubicle")
    for read, orig in zip(gt.objects, scene_gt, strict=True):
        np.testing.assert_allclose(read.box.center, orig.box.center, atol=1e-9)
        np.testing.assert_allclose(read.box.extents, orig.box.extents, atol=1e-9)
        np.testing.assert_allclose(read.box.rotation, orig.box.rotation, atol=1e-9)
    native = clio_metrics(estimates, scene_gt)
    via_clio = clio_metrics(estimates, gt.objects)
    assert_same_scores(native, via_clio)
    assert native.iou > 0.2 and native.strict_osr >= 0.5  # a non-trivial map: matches to preserve
    # Without the transform the boxes stay in Clio's frame, and the map no longer matches them.
    assert clio_metrics(estimates, load_clio_case(tmp_path / "tasks.yaml").objects).iou < native.iou / 2
    assert isinstance(to_gt, Similarity)
