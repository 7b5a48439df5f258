"""The outlier dial (`synthetic/outliers.py`, docs/research/ablation-decision.md): which frames it
replaces, that each kind of view is what it says (measured on the poses and in rendered id
images), that nothing else moves, and `bfields eval --outliers`'s argument checks."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bayesian_fields_core.cli.main import build_parser, main
from bayesian_fields_core.eval.synthetic.builder import build_scene
from bayesian_fields_core.eval.synthetic.cameras import capture_frames
from bayesian_fields_core.eval.synthetic.id_images import IdImageRenderer
from bayesian_fields_core.eval.synthetic.outliers import (
    FAR_MIN_DISTANCE,
    NEAR_GAP,
    OUTLIER_KINDS,
    blurred,
    outlier_views,
    ray_hits_box,
    task_object_ids,
    with_outliers,
)
from bayesian_fields_core.eval.synthetic.pieces import SyntheticScene
from bayesian_fields_core.eval.synthetic.spec import SceneSpec, suite_specs

LIGHT = {"object_density": 8000.0, "table_density": 1000.0, "room_density": 150.0}
SHARE = 0.3


def _spec(share: float = 0.0) -> SceneSpec:
    return with_outliers(suite_specs(suite="capture")[0].model_copy(update=LIGHT), share)


@pytest.fixture(scope="module")
def scene() -> SyntheticScene:
    return build_scene(_spec())


def _eye(w2c: np.ndarray) -> np.ndarray:
    return -w2c[:3, :3].T @ w2c[:3, 3]


def test_a_share_replaces_that_many_frames_in_equal_kinds_and_leaves_the_others(
    scene: SyntheticScene,
) -> None:
    spec = _spec(SHARE)
    before = capture_frames(_spec(), scene)
    after = capture_frames(spec, scene)
    views = outlier_views(spec, scene, len(after))
    replaced = [v.index for v in views]
    assert len(views) == round(SHARE * spec.n_frames) == 10
    counts = [sum(v.kind == k for v in views) for k in OUTLIER_KINDS]
    assert max(counts) - min(counts) <= 1 and min(counts) >= 3
    assert {v.instance_id for v in views} <= set(task_object_ids(spec, scene))
    for i, (a, b) in enumerate(zip(before, after, strict=True)):
        same = np.array_equal(a.world_to_camera, b.world_to_camera)
        assert same == (i not in replaced), i
        assert a.name == b.name and np.array_equal(a.K, b.K)


def test_share_zero_replaces_nothing_and_keeps_the_name() -> None:
    spec = suite_specs(suite="capture")[0]
    assert with_outliers(spec, 0.0) is spec
    assert with_outliers(spec, 0.15).name == "capture-a-o15"
    assert with_outliers(spec, 0.15).ground_truth_dump()["outlier_share"] == 0.15
    assert "outlier_share" not in spec.ground_truth_dump()


def test_the_dial_needs_an_occluder() -> None:
    with pytest.raises(ValueError, match="n_occluders"):
        SceneSpec(outlier_share=0.3)


def test_near_views_are_close_far_ones_far_and_occluded_ones_hidden(scene: SyntheticScene) -> None:
    spec = _spec(SHARE)
    by_id = {i.id: i for i in scene.instances}
    occluders = [i for i in scene.instances if i.name == "occluder"]
    ids = IdImageRenderer(scene.gaussians, scene.instance_ids)
    hiding = np.isin(scene.instance_ids, [o.id for o in occluders])
    bare = IdImageRenderer(scene.gaussians.subset(np.flatnonzero(~hiding)), scene.instance_ids[~hiding])
    occluded_px = unoccluded_px = 0
    frame = capture_frames(spec, scene)[0]
    for view in outlier_views(spec, scene, spec.n_frames):
        eye = _eye(view.world_to_camera)
        points = scene.gaussians.means[scene.instance_ids == view.instance_id]
        nearest = float(np.linalg.norm(points - eye, axis=1).min())
        image = ids.render(frame.K, view.world_to_camera, frame.width, frame.height)
        share = float((image == view.instance_id).mean())
        if view.kind == "near":
            assert nearest <= NEAR_GAP[1] + 1e-9
            assert share > 0.3  # the object fills much of the frame (a surface close up)
        elif view.kind == "far":
            assert np.linalg.norm(eye - by_id[view.instance_id].center) >= FAR_MIN_DISTANCE
            assert share < 0.002  # a few pixels (about 10 x 10 at most, of 320 x 240)
        else:
            target = by_id[view.instance_id].center
            assert any(ray_hits_box(eye, target, blurred(o)) for o in occluders)
            alone = bare.render(frame.K, view.world_to_camera, frame.width, frame.height)
            occluded_px += int((image == view.instance_id).sum())
            unoccluded_px += int((alone == view.instance_id).sum())
    # Rendered: the occluders hide most of the objects of the occluded views.
    assert unoccluded_px > 0 and occluded_px < 0.5 * unoccluded_px


def test_eval_outliers_arguments_are_checked(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    parser = build_parser()
    assert parser.parse_args(["eval", "--suite", "capture", "--outliers", "0.45"]).outliers == 0.45
    assert parser.parse_args(["eval"]).outliers == 0.0
    for bad in ("1.5", "-0.1", "lots"):
        with pytest.raises(SystemExit) as exc:
            parser.parse_args(["eval", "--outliers", bad])
        assert exc.value.code == 2
    assert "--outliers" in capsys.readouterr().err
    assert main(["eval", "--suite-dir", str(tmp_path / "s"), "--outliers", "0.3"]) == 2
    assert "--suite capture" in capsys.readouterr().err and not (tmp_path / "s").exists()
    args = ["eval", "--scene", str(tmp_path), "--gt", str(tmp_path / "gt.yaml"), "--outliers", "0.3"]
    assert main(args) == 2
    assert "does not go with --scene" in capsys.readouterr().err


def test_a_dial_scene_copies_the_frames_it_did_not_replace(tmp_path: Path) -> None:
    from bayesian_fields_core.eval.synthetic.generate import generate_scene

    tiny = {**LIGHT, "width": 64, "height": 48, "n_frames": 6}
    base_spec = suite_specs(suite="capture")[0].model_copy(update=tiny)
    spec = with_outliers(base_spec, 0.5)
    base = generate_scene(tmp_path / base_spec.name, base_spec)
    copied = generate_scene(tmp_path / spec.name, spec, images_from=base)
    fresh = generate_scene(tmp_path / "fresh", spec)
    replaced = {v.index for v in outlier_views(spec, build_scene(spec), spec.n_frames)}
    assert len(replaced) == 3
    for i in range(spec.n_frames):
        name = f"images/frame_{i:05d}.png"
        assert (copied / name).read_bytes() == (fresh / name).read_bytes()  # copying = rendering
        assert ((copied / name).read_bytes() == (base / name).read_bytes()) == (i not in replaced)
    assert (copied / "gt.json").read_text() == (fresh / "gt.json").read_text()
    # Another scene's folder is not a source.
    other = with_outliers(base_spec.model_copy(update={"seed": 1}), 0.5)
    generate_scene(tmp_path / "other", other, images_from=base)
    assert (tmp_path / "other/images/frame_00000.png").read_bytes() != (
        base / "images/frame_00000.png"
    ).read_bytes()
