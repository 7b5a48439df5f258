"""`bfields eval`: the method, its ablations and two baselines on the synthetic suite (Table 1).

The ablation "w/o PE" (`render_selection.py`) is not a pipeline run: it re-ranks the full row's
map by the cosine of a rendered view of each object, so it costs only those renders and encodes.

Every row runs on the same scenes, the same masks and the same CLIP embeddings: the first
(full-method) run fills the perception and visibility caches, every other row reuses them, so the
table isolates fusion and clustering. Scores are pooled over the suite's (task, GT object) pairs;
Objs and time are per-scene means; time counts perception once per scene for every row.
A second table scores the same maps by the LeRF protocol (`lerf_views.py`): per-scene mIoU /
mAcc of rendered object masks and their unweighted mean, as in the paper's Table 3.

Two scorings of the same boxes are printed (issue 33): "geometric", the project's (oriented
containment, Relaxed = either centre, pooled over the suite's pairs), and "Clio-code", the rules of
Clio's evaluation code that the paper's figures come from (`clio_code.py`). Intervals are given
twice: resampling tasks, and resampling scenes (a scene's tasks kept together).
The perception `regime` (`regime.py`) sets how much evidence one view carries: "realistic" (a real
CLIP's d' = 2.0, the default) or "strong" (the tiny CLIP as it is).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from bayesian_fields_core.calibration.model import distribution_min_peak
from bayesian_fields_core.errors import InputError
from bayesian_fields_core.eval.baselines import BaselineParams, clio_style, semantic_gaussians
from bayesian_fields_core.eval.bootstrap import paired_differences, score_intervals
from bayesian_fields_core.eval.breakdown import (
    SceneInstance,
    TaskBreakdown,
    format_breakdown,
    task_breakdowns,
)
from bayesian_fields_core.eval.clio import (
    ClioScores,
    EstimatedObject,
    GTObject,
    TaskScores,
    clio_metrics,
    format_table,
)
from bayesian_fields_core.eval.clio_code import CLIO_CODE_LABEL, clio_code_metrics, scene_mean
from bayesian_fields_core.eval.lerf import LerfScores, format_lerf_table
from bayesian_fields_core.eval.lerf_views import DEFAULT_VIEWS, LerfViews, prepare_views, score_map
from bayesian_fields_core.eval.not_found_intervals import format_shares, not_found_shares
from bayesian_fields_core.eval.not_found_tradeoff import (
    TaskOutcome,
    best_threshold,
    format_curve,
    format_not_found_table,
    task_outcomes,
    tradeoff_curve,
)
from bayesian_fields_core.eval.regime import DEFAULT_REGIME, Regime, describe, regime_models
from bayesian_fields_core.eval.render_selection import pe_selection
from bayesian_fields_core.eval.tables import format_interval_table
from bayesian_fields_core.fusion.likelihood import resolve_likelihood
from bayesian_fields_core.job.artifacts import RESULT_PREFIX
from bayesian_fields_core.job.factories import Job, local_job
from bayesian_fields_core.job.pipeline import run_job
from bayesian_fields_core.job.task_list import load_tasks
from bayesian_fields_core.objects.clustering import ObjectMap
from bayesian_fields_core.objects.not_found import SCORE_MEANING, resolve_answer_min_peak
from bayesian_fields_core.params import PipelineParams
from bayesian_fields_core.perception.models import Models, load_models
from bayesian_fields_core.results.format import Result
from bayesian_fields_core.results.reader import read_result

FULL = "Bayesian Fields (ours)"
AVERAGING = "  averaging instead of Bayes"
ORPHI = "  w/o OR-phi"
_OTHER_CONDITIONALS = "fused" if PipelineParams().aib_conditionals == "per_view" else "per_view"
METHOD_ROWS: dict[str, dict[str, Any]] = {
    FULL: {},
    ORPHI: {"outlier_rejection": False},
    "  w/o kNN filter": {"knn_filter": False},
    AVERAGING: {"fusion": "average"},
    # the clustering's other conditionals (issue 23): 'fused' is the paper's, 'per_view' the fix
    f"  AIB on {_OTHER_CONDITIONALS.replace('_', '-')} conditionals": {
        "aib_conditionals": _OTHER_CONDITIONALS
    },
}
WITHOUT_PE = "  w/o PE (cosine of a rendered view)"
"""The paper's "PE" ablation (`render_selection.py`): the full row's map, each task's answers
ranked by the cosine of a rendered view of each object instead of by probability; run after the
method rows from the full row's map, so it is not in `METHOD_ROWS` (those are pipeline runs)."""
RowSet = Literal["all", "full", "orphi"]
ROW_SETS: tuple[RowSet, ...] = ("all", "full", "orphi")
"""Which rows `bfields eval --rows` runs: every row (w/o PE included), the full method alone, or
the full method and w/o OR-phi (the outlier dial's pair, docs/research/ablation-decision.md)."""
SEMANTIC_GAUSSIANS = "Semantic Gaussians-style (avg. embeddings, best label)"
CLIO = "Clio-style (AIB on cosine, Clio's rows)"


@dataclass
class SceneEvaluation:
    """Every row's scores on one scene: Clio metrics, and LeRF ones when views were rendered;
    `not_found`: each row's task outcomes for the "not found" rule (empty for rows without its score)."""

    clio: dict[str, ClioScores]
    lerf: dict[str, LerfScores]
    not_found: dict[str, list[TaskOutcome]] = field(default_factory=dict)
    breakdown: dict[str, list[TaskBreakdown]] = field(default_factory=dict)
    clio_code: dict[str, ClioScores] = field(default_factory=dict)


@dataclass
class SceneCase:
    """One suite scene: its folder, tasks and ground truth."""

    name: str
    folder: Path
    tasks: list[str]
    ground_truth: list[GTObject]
    instances: list[SceneInstance] = field(default_factory=list)  # objects and clutter
    cache_name: str = ""
    """The cache folder's scene name when not `name`: a dial scene shares its base scene's cache
    (perception is keyed by image content, so the frames the dial left hit it)."""


def estimates_from_selection(
    tasks: list[str], selection: dict[str, list[tuple[int, Any]]]
) -> list[EstimatedObject]:
    """Estimated objects for Clio's metrics, queried in the map's own order.

    Each task's selection is already ranked by the map (the method ranks by `selection_score`,
    which need not be the stored conditional), so an object's score for a task is its rank
    turned into a decreasing number (1 for the best, then 1/2, 1/3...), and 0 for tasks that did
    not select it, so it is never queried there.
    """
    by_object: dict[int, EstimatedObject] = {}
    for task in tasks:
        for rank, (object_id, box) in enumerate(selection.get(task, [])):
            est = by_object.setdefault(object_id, EstimatedObject(box=box, probabilities={}))
            assert isinstance(est.probabilities, dict)  # made just above
            est.probabilities[task] = 1.0 / (rank + 1)
    return list(by_object.values())


def _estimates_from_map(tasks: list[str], object_map: ObjectMap) -> list[EstimatedObject]:
    selection = {
        task: [
            (int(o), object_map.boxes[o])
            for o in object_map.selection[t]
            if o >= 0 and object_map.boxes[o] is not None and object_map.probabilities[o, t] > 0
        ]
        for t, task in enumerate(tasks)
    }
    return estimates_from_selection(tasks, selection)


def _pooled_key(scene: int, task: str) -> str:
    """A task's key in the pooled scores: scenes may share task names."""
    return f"{scene}:{task}"


def scene_groups(per_scene: list[ClioScores]) -> dict[str, str]:
    """Pooled task key -> its scene (by index), for the scene-level bootstrap."""
    return {_pooled_key(i, task): str(i) for i, scores in enumerate(per_scene) for task in scores.per_task}


def pool_scores(per_scene: list[ClioScores]) -> ClioScores:
    """Micro-average over scenes: pooled (task, GT) pairs; mean Objs and time."""
    per_task: dict[str, TaskScores] = {}
    for i, scores in enumerate(per_scene):
        for task, ts in scores.per_task.items():
            per_task[_pooled_key(i, task)] = ts
    total = sum(ts.num_gt for ts in per_task.values())
    times = [s.time_s for s in per_scene if s.time_s is not None]
    return ClioScores(
        strict_osr=sum(ts.strict for ts in per_task.values()) / total,
        relaxed_osr=sum(ts.relaxed for ts in per_task.values()) / total,
        iou=sum(ts.iou_sum for ts in per_task.values()) / total,
        num_objects=int(round(float(np.mean([s.num_objects for s in per_scene])))),
        num_gt=total,
        per_task=per_task,
        time_s=float(np.mean(times)) if times else None,
    )


def prepare_scenes(
    suite_dir: Path,
    n_scenes: int,
    seeds: Sequence[int] | None = None,
    suite: str = "tabletop",
    outliers: float = 0.0,
) -> list[SceneCase]:
    """Generate (once; cached on disk) the named suite's scenes and read their tasks and GT.

    With `seeds`, the re-seeded held-out variants of the first ``len(seeds)`` scenes instead;
    `outliers` sets the outlier dial (`synthetic/outliers.py`; capture suite only), renaming
    the scenes when above 0."""
    from bayesian_fields_core.eval.synthetic import (
        generate_scene,
        load_clio_boxes,
        load_ground_truth,
        suite_specs,
    )
    from bayesian_fields_core.eval.synthetic.outliers import with_outliers
    from bayesian_fields_core.geometry.obb import OrientedBox

    if outliers > 0 and suite != "capture":
        raise InputError(f"the outlier dial is for the capture suite, not {suite!r}", source="eval")
    bases = suite_specs(seeds, suite=suite) if seeds else suite_specs(suite=suite)[:n_scenes]
    cases = []
    for base in bases:
        spec = with_outliers(base, outliers)
        folder = suite_dir / spec.name
        if not (folder / "gt.json").is_file():
            # With the dial on, the frames it leaves are those of the scene without it.
            generate_scene(folder, spec, images_from=suite_dir / base.name if spec is not base else None)
        cases.append(
            SceneCase(
                name=spec.name,
                cache_name=base.name,
                folder=folder,
                tasks=load_tasks(folder / "tasks.yaml"),
                ground_truth=load_clio_boxes(folder),
                instances=[
                    SceneInstance(i.name, OrientedBox(i.center, i.rotation, i.extents))
                    for i in load_ground_truth(folder).instances
                    if i.category == "object" or i.name == "clutter"
                ],
            )
        )
    return cases


def evaluate_scene(
    case: SceneCase,
    models: Models,
    out_dir: Path,
    *,
    base_params: dict[str, Any] | None = None,
    lerf_views: int = DEFAULT_VIEWS,
    log: Callable[[str], None] = print,
    rows_shown: RowSet = "all",
) -> SceneEvaluation:
    """All rows of both tables for one scene; `lerf_views=0` skips the LeRF protocol;
    `rows_shown="full"` runs only the full method, "orphi" it and w/o OR-phi (`ROW_SETS`)."""
    gt_per_task = {t: sum(1 for g in case.ground_truth if g.task == t) for t in case.tasks}
    top_k = max(5, max(gt_per_task.values(), default=1))
    cache_prefix = f"scenes/{case.cache_name or case.name}/cache/"
    rows: dict[str, ClioScores] = {}
    code_rows: dict[str, ClioScores] = {}
    lerf: dict[str, LerfScores] = {}
    not_found: dict[str, list[TaskOutcome]] = {}
    breakdown: dict[str, list[TaskBreakdown]] = {}
    views: LerfViews | None = None
    perceive_s = 0.0
    visibility_s = 0.0
    full_job: Job | None = None
    full_result: Result | None = None
    full_seconds = 0.0
    shown = {"all": list(METHOD_ROWS), "full": [FULL], "orphi": [FULL, ORPHI]}[rows_shown]
    method_rows = {row: METHOD_ROWS[row] for row in shown}
    for row, overrides in method_rows.items():
        # The first row checks the scene's alignment; the other rows run on the very same scene.
        # Previews off: the tables never look at them, and rendering them would add to every row.
        checked = {} if full_job is None else {"alignment_check": False}
        # Every task answered (the rule off), as the paper scores Table 1; the "not found" columns
        # apply the rule afterwards to each task's best candidate (eval/not_found.py).
        params = PipelineParams.model_validate(
            {"previews": False, **(base_params or {}), "top_k": top_k, **overrides, **checked}
            | {"answer_min_peak": None}
        )
        job = local_job(
            case.folder, out_dir / case.name / row_folder_name(row), out_dir / "cache", case.tasks, params, models,
            cache_prefix=cache_prefix,
        )  # fmt: skip
        store = job.spec.store
        reports = run_job(job, force=True)
        if full_job is None:
            full_job = job
            perceive_s = float(reports["perceive"]["seconds"])
            visibility_s = float(reports["fuse"]["seconds"])
            if lerf_views > 0:
                scene = job.scene.loaded
                views = prepare_views(case.folder, scene.gaussians, scene.frames, lerf_views)
        seconds = perceive_s + float(reports["fuse"]["seconds"]) + float(reports["cluster"]["seconds"])
        result = read_result(store, RESULT_PREFIX)
        if full_result is None:
            full_result, full_seconds = result, seconds
        # Boxes in the cameras' frame (where the GT lives; the splat file's frame may differ).
        selection = {
            task: [(o.object_id, o.capture_box or o.box) for o in objs]
            for task, objs in result.selections.items()
        }
        estimates = estimates_from_selection(case.tasks, selection)
        rows[row] = clio_metrics(estimates, case.ground_truth, num_objects=result.num_objects, time_s=seconds)
        code_rows[row] = clio_code_metrics(
            estimates, case.ground_truth, num_objects=result.num_objects, time_s=seconds
        )
        breakdown[row] = task_breakdowns(case.name, case.tasks, estimates, case.ground_truth, case.instances)
        best = {task: objs[0].peak if objs else None for task, objs in result.selections.items()}
        not_found[row] = task_outcomes(case.tasks, rows[row], best, scene=case.name)
        if views is not None:
            lerf[row] = score_map(views, case.tasks, result.object_ids, result.task_scores)
        log(_row_line(case.name, row, rows[row], lerf.get(row)))

    assert full_job is not None and full_result is not None
    if rows_shown != "all":
        return SceneEvaluation(
            clio=rows, lerf=lerf, not_found=not_found, breakdown=breakdown, clio_code=code_rows
        )
    text = models.encoder.encode_texts(case.tasks).astype(np.float32)
    full, full_scene = full_job.spec, full_job.scene
    t = time.perf_counter()
    pe = pe_selection(
        full, full_scene, full_result, models.encoder, text, full_job.runner.render_device(full.params)
    )
    own = time.perf_counter() - t
    seconds = full_seconds + own  # the full row's map, plus the renders and encodes
    pe_estimates = estimates_from_selection(case.tasks, pe.selection)
    rows[WITHOUT_PE] = clio_metrics(
        pe_estimates, case.ground_truth, num_objects=pe.num_objects, time_s=seconds
    )
    code_rows[WITHOUT_PE] = clio_code_metrics(
        pe_estimates, case.ground_truth, num_objects=pe.num_objects, time_s=seconds
    )
    breakdown[WITHOUT_PE] = task_breakdowns(
        case.name, case.tasks, pe_estimates, case.ground_truth, case.instances
    )
    if views is not None:
        lerf[WITHOUT_PE] = score_map(views, case.tasks, pe.object_ids, pe.scores)
    not_found[WITHOUT_PE] = []  # no per-view peak: the rule does not apply
    log(_row_line(case.name, WITHOUT_PE, rows[WITHOUT_PE], lerf.get(WITHOUT_PE)))
    log(
        f"  {case.name}: w/o PE's renders and encodes {own:.1f} s; {pe.selectable} of {pe.num_objects} objects seen"
    )
    likelihood = resolve_likelihood(full.params, models.calibration)
    mu0, mu1 = likelihood.mu0, likelihood.mu1
    for row, run in (
        (SEMANTIC_GAUSSIANS, lambda: semantic_gaussians(full, full_scene, text, BaselineParams(), mu0, mu1)),
        (CLIO, lambda: clio_style(full, full_scene, text, BaselineParams(), mu0, mu1)),
    ):
        t = time.perf_counter()
        object_map = run()
        seconds = perceive_s + visibility_s + time.perf_counter() - t
        baseline_estimates = _estimates_from_map(case.tasks, object_map)
        rows[row] = clio_metrics(
            baseline_estimates, case.ground_truth, num_objects=len(object_map.probabilities), time_s=seconds
        )
        code_rows[row] = clio_code_metrics(
            baseline_estimates, case.ground_truth, num_objects=len(object_map.probabilities), time_s=seconds
        )
        if views is not None:
            lerf[row] = score_map(views, case.tasks, object_map.object_ids, object_map.task_scores)
        not_found[row] = []  # no per-view peak: the rule does not apply
        log(_row_line(case.name, row, rows[row], lerf.get(row)))
    return SceneEvaluation(
        clio=rows, lerf=lerf, not_found=not_found, breakdown=breakdown, clio_code=code_rows
    )


def _row_line(scene: str, row: str, scores: ClioScores, lerf: LerfScores | None) -> str:
    line = f"  {scene}: {row.strip():<40} strict {scores.strict_osr:.2f}  iou {scores.iou:.2f}"
    return line if lerf is None else f"{line}  LeRF mIoU {lerf.miou:.2f}  mAcc {lerf.macc:.2f}"


def run_suite(
    *,
    suite_dir: Path,
    out_dir: Path,
    n_scenes: int = 5,
    profile: str | None = None,
    markdown: bool = False,
    base_params: dict[str, Any] | None = None,
    lerf_views: int = DEFAULT_VIEWS,
    seeds: Sequence[int] | None = None,
    not_found_curve: bool = False,
    suite: str = "tabletop",
    breakdown: bool = False,
    regime: Regime = DEFAULT_REGIME,
    rows_shown: RowSet = "all",
    outliers: float = 0.0,
) -> dict[str, ClioScores]:
    """Generate the suite, evaluate every row on every scene, print the pooled Table 1, the
    "not found" columns and, unless `lerf_views=0`, the LeRF table. `seeds` evaluates on held-out
    re-seeded scenes; `not_found_curve` adds the rule's threshold trade-off curve; `suite` names
    the suite ("tabletop", or "capture": handheld-capture effects, `synthetic/capture.py`);
    `breakdown` adds why each method row missed GT objects (`breakdown.py`), per task for the full
    method; `regime` is the perception regime (`regime.py`), the same for every row; `rows_shown`
    "full" runs the full method only (the "not found" answer and Table 1's first row, quickly);
    `outliers` is the outlier dial's share (capture suite; `synthetic/outliers.py`)."""
    models = regime_models(load_models(profile), regime)
    print(describe(models, regime))
    cases = prepare_scenes(suite_dir, n_scenes, seeds, suite, outliers)
    per_row: dict[str, list[ClioScores]] = {}
    code_per_row: dict[str, list[ClioScores]] = {}
    lerf_rows: dict[str, dict[str, LerfScores]] = {}
    outcomes: dict[str, list[TaskOutcome]] = {}
    causes: dict[str, list[TaskBreakdown]] = {}
    for case in cases:
        print(f"scene {case.name}: {len(case.tasks)} tasks, {len(case.ground_truth)} GT objects")
        scene_eval = evaluate_scene(
            case, models, out_dir, base_params=base_params, lerf_views=lerf_views, rows_shown=rows_shown
        )
        for row, scores in scene_eval.clio.items():
            per_row.setdefault(row, []).append(scores)
        for row, scores in scene_eval.clio_code.items():
            code_per_row.setdefault(row, []).append(scores)
        for row, lerf in scene_eval.lerf.items():
            lerf_rows.setdefault(row, {})[case.name] = lerf
        for row, task_list in scene_eval.not_found.items():
            outcomes.setdefault(row, []).extend(task_list)
        for row, task_causes in scene_eval.breakdown.items():
            causes.setdefault(row, []).extend(task_causes)
    pooled = {row: pool_scores(scores) for row, scores in per_row.items()}
    print()
    kind = "held-out" if seeds else "public"
    print(
        f"Synthetic suite {suite!r} ({kind} seeds{f', outlier share {outliers:g}' if outliers else ''}): "
        f"{len(cases)} scenes "
        f"({', '.join(c.name for c in cases)}), {pooled[FULL].num_gt} (task, GT object) pairs"
    )
    print(f"Geometric scoring (the project's: oriented containment, pooled over the pairs), regime {regime}:")
    print(format_table(pooled, markdown=markdown))
    print()
    code = {row: scene_mean(scores) for row, scores in code_per_row.items()}
    print(
        f"{CLIO_CODE_LABEL} scoring (Clio's evaluation code, as the paper's figures: axis-aligned "
        f"containment of twice the box, Relaxed = the estimate holds the GT centre, mean of the "
        f"{len(cases)} scenes), regime {regime}:"
    )
    print(format_table(code, markdown=markdown))
    print()
    print_intervals(pooled, scene_groups(per_row[FULL]), markdown=markdown)
    print_not_found(outcomes, run_threshold(base_params, models), markdown=markdown, curve=not_found_curve)
    print_not_found_shares(outcomes.get(FULL, []), base_params, models)
    if breakdown:
        print_breakdown(causes, markdown=markdown)
    if lerf_rows:
        queries = sum(s.num_queries for s in lerf_rows[FULL].values())
        print()
        print(f"LeRF protocol, mIoU / mAcc (%): {lerf_views} views per scene, {queries} (task, view) queries")
        print(
            format_lerf_table(
                {row.strip(): per_scene for row, per_scene in lerf_rows.items()}, markdown=markdown
            )
        )
    return pooled


def print_intervals(pooled: dict[str, ClioScores], groups: dict[str, str], *, markdown: bool = False) -> None:
    """The geometric scores' 95% intervals and the paired differences (full method minus each row,
    each Bayesian row minus averaging), by resampling tasks and, beside them, whole scenes."""
    n_tasks = len(pooled[FULL].per_task)
    n_scenes = len(set(groups.values()))
    for unit, unit_groups, count in (("tasks", None, n_tasks), ("scenes", groups, n_scenes)):
        print(f"The same scores with 95% intervals (bootstrap over the {count} {unit}):")
        intervals = {
            row.strip(): score_intervals(scores, groups=unit_groups) for row, scores in pooled.items()
        }
        print(format_interval_table(intervals, markdown=markdown))
        print()
    pairs = [(FULL, row) for row in pooled if row != FULL] + [
        (row, AVERAGING)
        for row in pooled
        if AVERAGING in pooled and row not in (AVERAGING, SEMANTIC_GAUSSIANS, CLIO, WITHOUT_PE)
    ]
    if not pairs:  # one row (`--rows full`): nothing to pair
        return
    print(
        f"Paired differences a - b (95%), bootstrap over the {n_tasks} tasks | over the {n_scenes} "
        "scenes (* = the interval excludes 0):"
    )
    for a, b in pairs:
        by_task = paired_differences(pooled[a], pooled[b])
        by_scene = paired_differences(pooled[a], pooled[b], groups=groups)
        cells = []
        for diff in (by_task, by_scene):
            marks = "".join("*" if d.significant else " " for d in diff.values())
            cells.append(f"strict {diff['strict_osr']}  IoU {diff['iou']} {marks}")
        name = f"{a.strip()} - {b.strip()}"
        print(f"  {name:<72} tasks: {cells[0]} | scenes: {cells[1]}")


def print_breakdown(causes: dict[str, list[TaskBreakdown]], *, markdown: bool = False) -> None:
    """Why GT objects were missed: per task for the full method, per task family for every row."""
    for row, rows in causes.items():
        print()
        print(
            f"Causes per (task, GT object), {row.strip()} (breakdown.py: merged = a neighbour inside the answer):"
        )
        print(format_breakdown(rows, markdown=markdown, per_task=row == FULL))


def run_threshold(base_params: dict[str, Any] | None, models: Models) -> float | None:
    """The `answer_min_peak` a run with `base_params` applies ('calibrated' resolved with the
    profile's calibration, as the cluster stage resolves it)."""
    params = PipelineParams.model_validate(base_params or {})
    return resolve_answer_min_peak(
        params.answer_min_peak, models.calibration, resolve_likelihood(params, models.calibration)
    )


def threshold_source(base_params: dict[str, Any] | None, models: Models) -> str:
    """Where the run's `answer_min_peak` comes from, in words (`run_threshold`)."""
    value = PipelineParams.model_validate(base_params or {}).answer_min_peak
    if value != "calibrated":
        return "given as a parameter"
    if getattr(models.calibration, "answer_min_peak", None) is not None:
        return "fitted by `bfields calibrate --scene` for this model and regime"
    return "the distribution threshold: no threshold fitted for this model and regime"


def print_not_found_shares(
    outcomes: list[TaskOutcome], base_params: dict[str, Any] | None, models: Models
) -> None:
    """The full method's shares with scene-level intervals at the run's threshold (and at the
    distribution threshold beside it, when the run's is another): issue 46's answer."""
    if not outcomes:
        return
    threshold = run_threshold(base_params, models)
    print()
    print(f"'Not found', full method, with 95% intervals resampling scenes ({SCORE_MEANING}):")
    print(
        format_shares(
            not_found_shares(outcomes, threshold),
            f"the run's threshold ({threshold_source(base_params, models)})",
        )
    )
    cal = models.calibration
    if cal is not None and cal.answer_min_peak is not None:
        fallback = distribution_min_peak(cal.mu0, cal.mu1, cal.s)
        print(format_shares(not_found_shares(outcomes, fallback), "the distribution threshold"))


def print_not_found(
    outcomes: dict[str, list[TaskOutcome]],
    threshold: float | None,
    *,
    markdown: bool = False,
    curve: bool = False,
) -> None:
    """The "not found" columns per row at the run's `threshold` (`run_threshold`) and, with
    `curve`, the full method's threshold trade-off curve and its best point (<= 5% recall lost)."""
    print()
    print(format_not_found_table(outcomes, threshold=threshold, markdown=markdown))
    if not curve or not outcomes.get(FULL):
        return
    points = tradeoff_curve(outcomes[FULL])
    print()
    print(f"Trade-off of the full method's answer_min_peak ({len(outcomes[FULL])} tasks):")
    print(format_curve(points, markdown=markdown))
    best = best_threshold(points)
    if best is not None:
        print(
            f"  most absent tasks 'not found' with <= 5% recall lost: threshold {best.threshold:.4g} "
            f"({100 * best.absent_share:.0f}% absent, {100 * best.recall_lost:.1f}% recall lost)"
        )


def row_folder_name(name: str) -> str:
    """The folder a row's run is written to under a scene's output (lower-case, dashes): bench
    scripts that read a row's run find it by the same rule."""
    return "".join(c if c.isalnum() else "-" for c in name.strip().lower()).strip("-")
