"""The w/o PE row's pieces (`eval/render_selection.py`) with the real renderer, visibility test and
tiny CLIP: the best view is the frame that sees most of an object, the crop holds only the
object's rendered pixels, and on a generated scene the cosine ranking puts the right objects first."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from bayesian_fields_core.eval.render_selection import (
    best_views,
    object_crop,
    object_footprint,
    pe_selection,
    rank_by_cosine,
    rendered_crops,
    to_uint8,
    visible_counts,
    visible_gaussians,
)
from bayesian_fields_core.eval.synthetic import generate_scene
from bayesian_fields_core.eval.synthetic.ground_truth import load_ground_truth
from bayesian_fields_core.eval.synthetic.spec import SceneSpec
from bayesian_fields_core.fusion.visibility import centre_columns
from bayesian_fields_core.job.artifacts import RESULT_PREFIX
from bayesian_fields_core.job.factories import local_job
from bayesian_fields_core.job.pipeline import run_job
from bayesian_fields_core.job.task_list import load_tasks
from bayesian_fields_core.params import PipelineParams, default
from bayesian_fields_core.perception.models import load_models
from bayesian_fields_core.render import GaussianRenderer
from bayesian_fields_core.results.reader import read_result
from bayesian_fields_core.scene.types import Frame, Gaussians

SH_C0 = 0.28209479177387814
SIZE = 64
K = np.array([[60.0, 0.0, SIZE / 2], [0.0, 60.0, SIZE / 2], [0.0, 0.0, 1.0]])


def _patch(x: tuple[float, float], y: tuple[float, float], z: float, colour: tuple[float, ...]) -> Gaussians:
    """A flat, opaque rectangle of Gaussians facing the z axis, of one colour, with no gaps."""
    xs, ys = np.meshgrid(np.linspace(*x, 24), np.linspace(*y, 24))
    step = max(x[1] - x[0], y[1] - y[0]) / 23
    n = xs.size
    means = np.stack([xs.ravel(), ys.ravel(), np.full(n, z)], axis=1).astype(np.float32)
    sh = ((np.asarray(colour, dtype=np.float32) - 0.5) / SH_C0)[None, None, :].repeat(n, axis=0)
    return Gaussians(
        means=means,
        log_scales=np.full((n, 3), np.log(step), dtype=np.float32),
        quats=np.tile(np.array([1.0, 0.0, 0.0, 0.0], dtype=np.float32), (n, 1)),
        opacity_logits=np.full(n, 6.0, dtype=np.float32),
        sh=sh,
    )


def _join(*parts: Gaussians) -> tuple[Gaussians, np.ndarray]:
    """The parts as one splat, and (N,) each Gaussian's part index."""

    def cat(name: str) -> np.ndarray:
        return np.concatenate([getattr(p, name) for p in parts])

    joined = Gaussians(
        means=cat("means"),
        log_scales=cat("log_scales"),
        quats=cat("quats"),
        opacity_logits=cat("opacity_logits"),
        sh=cat("sh"),
    )
    return joined, np.concatenate([np.full(len(p), i) for i, p in enumerate(parts)])


def _frame(name: str, w2c: np.ndarray) -> Frame:
    return Frame(name=name, K=K, world_to_camera=w2c, width=SIZE, height=SIZE)


def _pose(rotation: np.ndarray, centre: tuple[float, float, float]) -> np.ndarray:
    w2c = np.eye(4)
    w2c[:3, :3] = rotation
    w2c[:3, 3] = -rotation @ np.asarray(centre)
    return w2c


def test_the_best_view_is_the_frame_that_sees_most_of_the_object() -> None:
    torch.set_num_threads(1)
    # object 0: a square at z = 3; object 1: a wall at z = 4.5, between it and a camera behind.
    splat, ids = _join(
        _patch((-0.4, 0.4), (-0.4, 0.4), 3.0, (1, 0, 0)), _patch((-1, 1), (-1, 1), 4.5, (0, 0, 1))
    )
    frames = [
        _frame("edge", _pose(np.eye(3), (1.5, 0.0, 0.0))),  # the square half out of the image
        _frame("front", _pose(np.eye(3), (0.0, 0.0, 0.0))),  # the whole square, facing it
        _frame("behind", _pose(np.diag([-1.0, 1.0, -1.0]), (0.0, 0.0, 6.0))),  # the wall hides it
    ]
    renderer = GaussianRenderer(splat, backend="torch")
    centres = centre_columns(splat.means, "cpu")
    visible = []
    for f in frames:
        depth = renderer.render(f.K, f.world_to_camera, f.width, f.height, depth_only=True).median_depth
        visible.append(
            visible_gaussians(
                centres,
                f,
                depth,
                depth_tolerance=0.05,
                relative_tolerance=default("depth_tolerance_relative"),
                near=1e-3,
            )
        )
    counts = visible_counts(ids, visible, 2)
    # front sees all of the square, the edge view about half, the view behind the wall none
    assert counts[1, 0] == np.count_nonzero(ids == 0)
    assert 0.3 * counts[1, 0] < counts[0, 0] < 0.7 * counts[1, 0]
    assert counts[2, 0] == 0
    assert counts[2, 1] > 0  # what the view behind sees instead: the wall
    assert best_views(counts)[0] == 1
    # an object no frame sees is not selectable; ties go to the earliest frame
    assert best_views(np.array([[0, 3], [0, 3]])).tolist() == [-1, 0]


def test_the_crop_keeps_only_the_objects_rendered_pixels() -> None:
    torch.set_num_threads(1)
    # red object 0 and green object 1 side by side, a blue wall (no object) behind both.
    splat, parts = _join(
        _patch((-0.6, -0.1), (-0.3, 0.3), 3.0, (1, 0, 0)),
        _patch((0.1, 0.6), (-0.3, 0.3), 3.0, (0, 1, 0)),
        _patch((-2, 2), (-2, 2), 5.0, (0, 0, 1)),
    )
    ids = np.where(parts == 2, -1, parts)
    frame = _frame("front", _pose(np.eye(3), (0.0, 0.0, 0.0)))
    renderer = GaussianRenderer(splat, backend="torch")
    scene = renderer.render(K, frame.world_to_camera, SIZE, SIZE)
    alone = GaussianRenderer(splat.subset(ids == 0), backend="torch").render(
        K, frame.world_to_camera, SIZE, SIZE
    )
    assert scene.rgb is not None
    image = to_uint8(scene.rgb)
    footprint = object_footprint(
        alone.alpha, alone.median_depth, scene.median_depth, depth_tolerance=0.05, relative_tolerance=0.0
    )
    # the object alone behind an occluder is not its footprint: the green patch moved in front of it
    hidden = GaussianRenderer(
        _join(splat, _patch((-0.6, -0.1), (-0.3, 0.3), 2.0, (0, 1, 0)))[0], backend="torch"
    )
    covered = object_footprint(
        alone.alpha,
        alone.median_depth,
        hidden.render(K, frame.world_to_camera, SIZE, SIZE).median_depth,
        depth_tolerance=0.05,
        relative_tolerance=0.0,
    )
    assert footprint.sum() > 100 and covered.sum() < 0.05 * footprint.sum()
    crop = object_crop(image, footprint)
    assert crop is not None and crop.shape[0] == crop.shape[1] < SIZE
    lit = crop.max(axis=-1) > 0
    assert lit.mean() > 0.4  # the object fills most of its crop
    red = crop[lit].astype(int)
    # only red (its edge blends into the wall behind): no green object, no blue wall
    assert np.all(red[:, 0] > red[:, 1:].max(axis=1)) and np.mean(red[:, 0] > 200) > 0.8
    assert object_crop(image, np.zeros((SIZE, SIZE), dtype=bool)) is None


@pytest.mark.slow  # one pipeline run on a small generated scene: ~15 s
def test_the_cosine_ranking_puts_a_tasks_object_first(tmp_path: Path) -> None:
    torch.set_num_threads(1)
    folder = tmp_path / "small"
    generate_scene(
        folder,
        SceneSpec(
            name="small", seed=5, n_objects=4, n_duplicates=0, n_colours=3, n_groups=2, n_frames=8,
            width=192, height=144, object_density=12000, table_density=1200, room_density=150,
        ),
    )  # fmt: skip
    tasks = load_tasks(folder / "tasks.yaml")
    models = load_models(None)
    params = PipelineParams.model_validate({"previews": False, "answer_min_peak": None})
    job = local_job(folder, tmp_path / "out", tmp_path / "cache", tasks, params, models)
    run_job(job)
    result = read_result(job.spec.store, RESULT_PREFIX)
    text = models.encoder.encode_texts(tasks).astype(np.float32)

    pe = pe_selection(job.spec, job.scene, result, models.encoder, text)
    # each task takes as many answers as the full method gave it, from the objects some view shows
    assert [len(pe.selection[t]) for t in tasks] == [len(result.selections[t]) for t in tasks]
    assert 0 < pe.selectable <= pe.num_objects

    # The ranking itself, on the scene's true instances as the map's objects (so a fragment of the
    # map cannot stand in for its object): each one-object task's object comes first.
    gt = load_ground_truth(folder)
    crops = rendered_crops(job.spec, job.scene, gt.instance_ids, int(gt.instance_ids.max()) + 1)
    single = {t.text: t.objects[0].instance_id for t in gt.tasks if len(t.objects) == 1}
    columns = [tasks.index(task) for task in single]
    assert len(single) >= 3
    ranked, _ = rank_by_cosine(models.encoder, crops, text[columns], [3] * len(columns))
    firsts = [r[0] == truth for r, truth in zip(ranked, single.values(), strict=True)]
    assert np.mean(firsts) >= 0.75, (firsts, ranked, single)
    # ranked upside down (lowest cosine first), none comes first
    upside_down, _ = rank_by_cosine(models.encoder, crops, -text[columns], [3] * len(columns))
    assert not any(r[0] == truth for r, truth in zip(upside_down, single.values(), strict=True))


@pytest.mark.slow  # three small scenes through every row of `bfields eval`: ~40 s
def test_bfields_eval_prints_the_row_in_its_tables(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from bayesian_fields_core.cli.main import main
    from bayesian_fields_core.eval.synthetic.spec import suite_specs

    torch.set_num_threads(1)
    suite_dir = tmp_path / "suite"
    for spec in suite_specs()[:3]:  # the suite's first three scenes, made small (the CLI reuses them)
        small = spec.model_copy(
            update={"width": 96, "height": 72, "n_frames": 6, "object_density": 6000.0,
                    "table_density": 800.0, "room_density": 100.0}
        )  # fmt: skip
        generate_scene(suite_dir / spec.name, small)
    args = ["eval", "--suite-dir", str(suite_dir), "--out", str(tmp_path / "out"), "--scenes", "3"]
    assert main([*args, "--lerf-views", "0", "--rows", "all"]) == 0
    out = capsys.readouterr().out
    table1, code_table = out.split("Geometric scoring")[1].split("Clio-code scoring")
    assert "w/o PE" in table1 and "w/o PE" in code_table.split("95% intervals")[0]
    assert "Bayesian Fields (ours) - w/o PE (cosine of a rendered view)" in out  # its paired difference
    assert main([*args, "--lerf-views", "0", "--rows", "full"]) == 0
    assert "w/o PE" not in capsys.readouterr().out
