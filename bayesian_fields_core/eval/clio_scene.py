"""`bfields eval --scene DIR --gt FILE [--transform FILE]`: Table 1 on one scene with Clio's ground truth.

The scene folder is any scene `bfields run` reads (a splat trained on the dataset's COLMAP
poses, its cameras and images); the tasks are the ground truth's keys, in file order, including
tasks with no box (absent tasks, scored by the "not found" columns). Every row of the suite's
Table 1 runs on the scene (`suite.evaluate_scene`: the method, its ablations, the two baselines,
on one shared perception); the table is printed with the paired task-bootstrap intervals of the
full method against each row. The LeRF table needs per-Gaussian ground truth, which Clio's
datasets do not have, so it is skipped.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.eval.bootstrap import paired_differences
from bayesian_fields_core.eval.clio import ClioScores, format_table
from bayesian_fields_core.eval.clio_format import load_clio_case
from bayesian_fields_core.eval.suite import FULL, SceneCase, evaluate_scene, print_not_found, run_threshold
from bayesian_fields_core.perception.models import load_models


def clio_case(
    scene_dir: Path, gt_file: Path, transform_file: Path | None = None, transform_key: str | None = None
) -> SceneCase:
    """The scene with Clio's tasks and GT boxes mapped into its capture (COLMAP) frame."""
    if not scene_dir.is_dir():
        raise InputError("not a folder", source=str(scene_dir))
    gt = load_clio_case(gt_file, transform_file, transform_key, default_key=scene_dir.resolve().name)
    return SceneCase(name=scene_dir.resolve().name, folder=scene_dir, tasks=gt.tasks, ground_truth=gt.objects)


def run_clio_scene(
    *,
    scene_dir: Path,
    gt_file: Path,
    out_dir: Path,
    transform_file: Path | None = None,
    transform_key: str | None = None,
    profile: str | None = None,
    markdown: bool = False,
    base_params: dict[str, Any] | None = None,
    not_found_curve: bool = False,
) -> dict[str, ClioScores]:
    """Evaluate every Table 1 row on one scene against Clio-format ground truth and print it."""
    case = clio_case(scene_dir, gt_file, transform_file, transform_key)
    absent = [t for t in case.tasks if all(g.task != t for g in case.ground_truth)]
    print(
        f"scene {case.name}: {len(case.tasks)} tasks ({len(absent)} without a GT object), "
        f"{len(case.ground_truth)} GT objects"
    )
    models = load_models(profile)
    evaluation = evaluate_scene(case, models, out_dir, base_params=base_params, lerf_views=0)
    rows = evaluation.clio
    print()
    print(f"Table 1 on {case.name}: {rows[FULL].num_gt} (task, GT object) pairs")
    print(format_table(rows, markdown=markdown))
    print()
    print(f"Full method minus each row, paired bootstrap over the {len(rows[FULL].per_task)} tasks (95%):")
    for row, scores in rows.items():
        if row == FULL:
            continue
        diff = paired_differences(rows[FULL], scores)
        marks = "".join("*" if d.significant else " " for d in diff.values())
        print(f"  {row.strip():<56} strict {diff['strict_osr']}  IoU {diff['iou']}  {marks}")
    print("  (* = the interval excludes 0)")
    threshold = run_threshold(base_params, models)
    print_not_found(evaluation.not_found, threshold, markdown=markdown, curve=not_found_curve)
    return rows
