"""`bfields eval`'s machinery on one small generated scene: every row of Table 1 is computed from
real pipeline runs and real baselines on shared perception, and the table prints."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bayesian_fields_core.eval.lerf_views import prepare_views, score_map
from bayesian_fields_core.eval.suite import (
    CLIO,
    FULL,
    METHOD_ROWS,
    SEMANTIC_GAUSSIANS,
    WITHOUT_PE,
    SceneCase,
    evaluate_scene,
)
from bayesian_fields_core.eval.synthetic import generate_scene, load_clio_boxes
from bayesian_fields_core.eval.synthetic.ground_truth import load_ground_truth
from bayesian_fields_core.eval.synthetic.spec import SceneSpec
from bayesian_fields_core.job.task_list import load_tasks
from bayesian_fields_core.perception.models import load_models
from bayesian_fields_core.scene.loader import load_scene

# Slow (the inner loop leaves it out): its fixtures took 5.5 s to set up here (--durations).
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def small_case(tmp_path_factory: pytest.TempPathFactory) -> SceneCase:
    folder = tmp_path_factory.mktemp("suite") / "small"
    spec = SceneSpec(
        name="small", seed=5, n_objects=4, n_duplicates=0, n_colours=3, n_groups=2, n_frames=8,
        width=192, height=144, object_density=12000, table_density=1200, room_density=150,
    )  # fmt: skip
    generate_scene(folder, spec)
    return SceneCase(
        name="small",
        folder=folder,
        tasks=load_tasks(folder / "tasks.yaml"),
        ground_truth=load_clio_boxes(folder),
    )


def test_every_row_is_scored_on_the_same_perception(small_case: SceneCase, tmp_path: Path) -> None:
    import torch

    torch.set_num_threads(1)
    models = load_models(None)
    lines: list[str] = []
    evaluation = evaluate_scene(small_case, models, tmp_path, lerf_views=2, log=lines.append)
    rows = evaluation.clio
    assert set(rows) == {*METHOD_ROWS, WITHOUT_PE, SEMANTIC_GAUSSIANS, CLIO}
    n_gt = len(small_case.ground_truth)
    for name, scores in rows.items():
        assert scores.num_gt == n_gt, name
        assert 0.0 <= scores.strict_osr <= scores.relaxed_osr <= 1.0, name
        assert 0.0 <= scores.iou <= 1.0, name
    # The scene's objects are few, distinct and well separated: the full method finds most of them.
    # (measured: strict 0.83, IoU 0.71 with the bundled tiny CLIP)
    assert rows[FULL].strict_osr >= 0.6
    assert rows[FULL].iou > 0.4
    # The Clio-code scoring of the same boxes: the same IoU and pairing, other containment.
    assert set(evaluation.clio_code) == set(rows)
    for name, code in evaluation.clio_code.items():
        assert code.iou == pytest.approx(rows[name].iou), name
        assert 0.0 <= code.strict_osr <= code.relaxed_osr <= 1.0, name
    # Perception ran once (one cache) and every method row wrote its own result.
    assert len(list((tmp_path / "cache").rglob("*.npz"))) > 0
    assert len(lines) == len(rows) + 1  # a line per row, and one with the w/o PE row's own cost
    # The same maps scored by the LeRF protocol on two rendered views.
    assert set(evaluation.lerf) == set(rows)
    for name, lerf in evaluation.lerf.items():
        assert lerf.num_queries == evaluation.lerf[FULL].num_queries > 0, name
        assert 0.0 <= lerf.miou <= 1.0 and 0.0 <= lerf.macc <= 1.0, name
    # Far above chance on 9 queries (measured 4/9 with the label-trained tiny CLIP, 5/9 before).
    assert evaluation.lerf[FULL].macc >= 0.4


def test_lerf_scores_a_perfect_map_one_and_a_wrong_one_low(small_case: SceneCase) -> None:
    gt = load_ground_truth(small_case.folder)
    scene = load_scene(small_case.folder)
    views = prepare_views(small_case.folder, scene.gaussians, scene.frames, 3)
    # The GT instances as the map's objects, each certain for the tasks it belongs to.
    n_instances = int(gt.instance_ids.max()) + 1
    truth = np.zeros((n_instances, len(small_case.tasks)))
    for task in gt.tasks:
        truth[[o.instance_id for o in task.objects], small_case.tasks.index(task.text)] = 1.0
    perfect = score_map(views, small_case.tasks, gt.instance_ids, truth)
    assert perfect.num_queries >= 3
    assert perfect.miou == pytest.approx(1.0)
    assert perfect.macc == 1.0
    # Every task pointed at some other task's objects: no overlap with the GT masks.
    wrong = score_map(views, small_case.tasks, gt.instance_ids, np.roll(truth, 1, axis=1))
    assert wrong.num_queries == perfect.num_queries
    assert wrong.miou < 0.3


def test_the_orphi_row_set_runs_the_full_method_and_w_o_or_phi(small_case: SceneCase, tmp_path: Path) -> None:
    """`--rows orphi` (the outlier dial's pair): exactly those two rows, on the same perception."""
    from bayesian_fields_core.eval.suite import ORPHI

    lines: list[str] = []
    evaluation = evaluate_scene(
        small_case, load_models(None), tmp_path, lerf_views=0, log=lines.append, rows_shown="orphi"
    )
    assert set(evaluation.clio) == set(evaluation.clio_code) == {FULL, ORPHI}
    assert len(lines) == 2 and "w/o OR-phi" in lines[1]
