"""Done-when of issue 10, deliverable 1: the pipeline on each trainer's output folder (built as the
trainer writes it from the tiny rendered scene) gives the untransformed scene's result: object ids
agree on >= 99% of Gaussians after matching labels, capture-frame centroids agree, and the splat-
frame boxes, centroids and exports are in the frame of the splat file the user gave."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.job.pipeline import run_job
from bayesian_fields_core.job.store import LocalStore
from bayesian_fields_core.params import PipelineParams
from bayesian_fields_core.results.reader import read_result
from bayesian_fields_core.scene.loader import load_scene
from bayesian_fields_core.scene.ply import read_ply
from bayesian_fields_core.scene.similarity import Similarity
from tests.core.conftest import counting_models, make_job
from tests.core.scene.trainer_layouts import (
    NS_PROCESS_DATA_APPLIED,
    SourceScene,
    gsplat_output,
    inria_output,
    scene_yaml_output,
    splatfacto_output,
)

# Slow (the inner loop leaves it out): its fixtures took 5.6 s to set up here (--durations).
pytestmark = pytest.mark.slow


def _run(scene: Path, root: Path, profile: dict[str, Any], **kwargs: Any):
    job = make_job(scene, root / "job", root / "cache", counting_models(profile), **kwargs)
    run_job(job)
    return read_result(LocalStore(root / "job"), "job/result/")


@pytest.fixture(scope="module")
def baseline(scene_dir: Path, profile: dict[str, Any], tmp_path_factory: pytest.TempPathFactory):
    return _run(scene_dir, tmp_path_factory.mktemp("layout-baseline"), profile)


def matched_agreement(a: np.ndarray, b: np.ndarray) -> tuple[float, dict[int, int]]:
    """Share of Gaussians whose object ids agree after the best one-to-one relabelling of b's
    objects to a's (-1 = none maps only to -1), and that relabelling."""
    la, lb = np.unique(a), np.unique(b)
    table = np.zeros((len(la), len(lb)), dtype=np.int64)
    np.add.at(table, (np.searchsorted(la, a), np.searchsorted(lb, b)), 1)
    none_a, none_b = la == -1, lb == -1
    table[np.ix_(none_a, ~none_b)] = 0
    table[np.ix_(~none_a, none_b)] = 0
    rows, cols = linear_sum_assignment(-table)
    return table[rows, cols].sum() / len(a), {int(lb[c]): int(la[r]) for r, c in zip(rows, cols, strict=True)}


def _layout(name: str, src: SourceScene, tmp: Path) -> tuple[Path, dict[str, Any]]:
    if name == "inria":
        return inria_output(src, tmp / "output", tmp / "dataset"), {"allow_source_path": True}
    if name == "splatfacto":
        return splatfacto_output(src, tmp / "ns"), {}
    if name == "gsplat":
        return gsplat_output(src, tmp / "garden"), {}
    rot = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    return scene_yaml_output(src, tmp / "any", Similarity(0.5, rot, np.array([0.4, -0.3, 0.2]))), {}


@pytest.mark.parametrize("layout", ["inria", "splatfacto", "gsplat", "scene.yaml"])
def test_trainer_layout_gives_the_untransformed_result(
    layout: str, baseline, scene_dir: Path, profile: dict[str, Any], tmp_path: Path
) -> None:
    source = load_scene(scene_dir)
    folder, kwargs = _layout(layout, SourceScene(source.gaussians, source.frames), tmp_path)
    result = _run(folder, tmp_path / "run", profile, **kwargs)
    scene = load_scene(folder, **kwargs)

    agreement, relabel = matched_agreement(baseline.object_ids, result.object_ids)
    assert agreement >= 0.99, agreement
    print(f"{layout}: object ids agree on {agreement:.4%} of {len(result.object_ids)} Gaussians")
    assert result.tasks == baseline.tasks
    transformed = scene.splat_to_capture is not None
    assert transformed == (layout != "inria")
    assert (result.splat_to_capture is not None) == transformed
    # ns-process-data's transforms.json poses are applied_transform @ COLMAP world: results are
    # also given in that world (the user's own COLMAP frame), and only there is one to undo.
    to_world = None
    if layout == "splatfacto":
        to_world = Similarity.from_matrix(NS_PROCESS_DATA_APPLIED, source="applied").inverse()
        np.testing.assert_allclose(result.capture_to_world, to_world.matrix, atol=1e-12)
    else:
        assert result.capture_to_world is None
    splat_file = read_ply(scene.splat_path)
    for task in result.tasks:
        ours = {relabel.get(o.object_id, -2): o for o in result.selections[task]}
        theirs = {o.object_id: o for o in baseline.selections[task]}
        assert set(ours) == set(theirs), task
        for object_id, obj in ours.items():
            ref = theirs[object_id]
            capture = obj.capture_centroid if transformed else obj.centroid
            np.testing.assert_allclose(capture, ref.centroid, atol=1e-3)
            if to_world is None:
                assert obj.world_centroid is None and obj.world_box is None
            else:
                np.testing.assert_allclose(obj.world_centroid, to_world.points(ref.centroid), atol=1e-3)
                np.testing.assert_allclose(obj.world_box.center, to_world.points(obj.capture_box.center))
            # The reported centroid is in the splat file's frame: the mean of its own Gaussians there.
            members = result.object_ids == obj.object_id
            np.testing.assert_allclose(
                obj.centroid, splat_file.means[members].astype(np.float64).mean(axis=0), atol=1e-4
            )
            grown = type(obj.box)(obj.box.center, obj.box.rotation, obj.box.extents * (1 + 1e-5) + 1e-6)
            assert grown.contains(splat_file.means[members].astype(np.float64)).all()
            if transformed:
                to_splat = scene.splat_to_capture.inverse()
                np.testing.assert_allclose(obj.centroid, to_splat.points(obj.capture_centroid), atol=1e-6)
                np.testing.assert_allclose(
                    obj.box.extents, obj.capture_box.extents * to_splat.scale, rtol=1e-6
                )
    # Exports are in the splat file's frame too, so they overlay the user's splat.
    some = next((o for objs in result.selections.values() for o in objs), None)
    assert some is not None and some.export is not None
    exported = read_ply(tmp_path / "run" / "job" / "job" / "result" / some.export)
    np.testing.assert_allclose(
        exported.means, splat_file.means[result.object_ids == some.object_id], atol=1e-4
    )


def test_untransformed_splatfacto_splat_does_not_agree(
    baseline, scene_dir: Path, profile: dict[str, Any], tmp_path: Path
) -> None:
    """Control: the same export without its dataparser transform is not the scene, so the check
    above can fail; the alignment check refuses such a run unless it is switched off."""
    source = load_scene(scene_dir)
    folder = splatfacto_output(SourceScene(source.gaussians, source.frames), tmp_path / "ns")
    (folder / "dataparser_transforms.json").unlink()
    with pytest.raises(InputError, match="alignment"):
        _run(folder, tmp_path / "refused", profile)
    result = _run(folder, tmp_path / "run", profile, params=PipelineParams(alignment_check=False))
    agreement, _ = matched_agreement(baseline.object_ids, result.object_ids)
    print(
        f"untransformed splatfacto: {agreement:.4%}; baseline in objects: {(baseline.object_ids >= 0).mean():.2%}"
    )
    assert agreement < 0.9, agreement


def test_cli_splat_transform_and_source_path(
    scene_dir: Path, profile_yaml: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`bfields run --splat-transform FILE` applies a transform kept outside the folder, and the
    JSON summary carries both frames; the CLI follows a 3DGS cfg_args source_path."""
    import json

    from bayesian_fields_core.cli.main import main

    source = load_scene(scene_dir)
    src = SourceScene(source.gaussians, source.frames)
    folder = splatfacto_output(src, tmp_path / "ns")
    transform = tmp_path / "dataparser_transforms.json"
    (folder / "dataparser_transforms.json").rename(transform)
    common = ["--cache-dir", str(tmp_path / "cache"), "--profile", str(profile_yaml), "-q", "--json"]
    args = ["run", str(folder), "--out", str(tmp_path / "out"), "--task", "red chair", *common]
    assert main([*args, "--splat-transform", str(transform)]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["frames"]["layout"] == "nerfstudio"
    to_capture = Similarity.from_matrix(summary["frames"]["splat_to_capture"], source="summary")
    objects = summary["selections"][0]["objects"]
    assert summary["selections"][0]["task"] == "red chair" and objects
    for obj in objects:
        np.testing.assert_allclose(
            to_capture.points(obj["centroid"]), obj["capture_frame"]["centroid"], atol=1e-3
        )

    out = inria_output(src, tmp_path / "output", tmp_path / "dataset")
    assert main(["run", str(out), "--out", str(tmp_path / "out2"), "--task", "red chair", *common]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["frames"]["layout"] == "inria" and list(summary["frames"]["names"]) == ["splat"]
    assert summary["frames"]["splat_to_capture"] is None and summary["frames"]["capture_to_world"] is None
