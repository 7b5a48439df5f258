"""Why the full method merges neighbouring objects that averaging keeps apart (issue 23, item 1).

The suspected chain: per-Gaussian evidence saturates (p -> 1 after a few confusable views), so
neighbouring primitives share the same normalised p(y|x) (null = prod(1 - p) -> 0), and they are
joined at no information cost, either by the identical-vectors pre-merge (METHOD step 8,
`identical_tolerance`) or by the AIB at (near) zero cost. This script measures each link on the
synthetic suites, for the full method as the paper clusters it (`fusion=bayes`,
`aib_conditionals=fused`), with the per-view conditionals of the fix (`per_view`) and for
averaging (`fusion=average`):

1. saturation: the share of (Gaussian, task) pairs with p > 0.999, against the Gaussian's number
   of accepted views, split into pairs where the Gaussian belongs to a GT object of the task
   ("relevant") or not ("irrelevant"); per task, the share of observed Gaussians and of
   primitives (mean p) saturated;
2. the rows: how many primitives' p(y|x) are still the prior's, all-null (every task < 0.001) or
   a saturation pattern (every task < 0.001 or > 0.999, one at least above);
3. the merges: the pre-merge's unions by row pattern, and the AIB's merges by relative cost
   (`d_ij / I(X;Y)`: exactly 0, < 1e-9, < 1e-7, < 1e-6, and all of them, which the stopping rule
   bounds by `aib_delta`), each split by what they join in the ground truth: the dominant GT
   instance (by Gaussians) of both sides is the same object, two different objects, an object
   and background (room, table, clutter), or background twice;
4. the outcome: final objects holding >= 25 % of the Gaussians of two or more GT objects, and the
   stage (pre-merge or AIB) of the first object-object join inside each.

The clustering is not re-implemented here: the pipeline runs as `bfields eval` runs it
(`run_job`, perception cached per scene), then steps 8-12 are called again on the stored
artifacts to read their `MergeLog` (`objects.clustering`), and the replayed map is checked to
equal the stored result's object ids.

Prints the tables, writes a JSON of every number (per task and per scene too) and a PNG figure
(drawn with PIL like `plot_capture_effects.py`: the project has no plotting library).

Usage: ``nice -n 10 .venv/bin/python bench/merge_mechanism.py [--suites tabletop,capture]
[--scenes 5] [--suite-dir build/suites] [--out build/merge-mechanism] [--figure
docs/research/merge-mechanism.png] [--json docs/research/merge-mechanism.json]``
(about 15 minutes for both suites from nothing on 2 busy CPU cores, scene generation included;
about 3 over warm caches).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bayesian_fields_core.eval.suite import SceneCase, prepare_scenes
from bayesian_fields_core.eval.synthetic import load_ground_truth
from bayesian_fields_core.job.artifacts import ACCEPTED_KEY, FUSION_KEY, RESULT_PREFIX
from bayesian_fields_core.job.factories import Job, local_job
from bayesian_fields_core.job.pipeline import run_job
from bayesian_fields_core.job.store import get_arrays
from bayesian_fields_core.objects.clustering import MergeLog, objects_from_primitives, primitive_scores
from bayesian_fields_core.objects.probabilities import conditionals, primitive_means
from bayesian_fields_core.params import PipelineParams
from bayesian_fields_core.perception.models import Models, load_models
from bayesian_fields_core.results.reader import read_result
from bayesian_fields_core.stages.cluster import load_primitives, view_counts

SATURATED = 0.999
"""p above which a Gaussian (or a primitive's mean) counts as saturated (issue 23's definition)."""
LOW = 1e-3
"""p below which a task counts as confidently irrelevant (the mirror of `SATURATED`)."""
NEAR_ZERO = (1e-9, 1e-7, 1e-6)
"""Relative AIB costs `d_ij / I(X;Y)` reported as "near zero"; every AIB merge is below
`aib_delta` (1e-5) by the stopping rule, so the last column "all" is that bound."""
VIEW_BINS = (0, 1, 2, 3, 5, 9, 17, 33)
"""Left edges of the accepted-view bins: 0, 1, 2, 3-4, 5-8, 9-16, 17-32, 33+."""
SPAN_SHARES = (0.1, 0.25)
"""A final object "spans" a GT object when it holds at least this share of its Gaussians."""
ROWS: dict[str, dict[str, str]] = {
    "bayes": {"fusion": "bayes", "aib_conditionals": "fused"},  # the paper's clustering input
    "per_view": {"fusion": "bayes", "aib_conditionals": "per_view"},  # issue 23's fix (default)
    "average": {"fusion": "average"},
}
"""The runs per scene: the full method as the paper clusters it ('bayes', the row the mechanism
was first measured on), with the per-view conditionals (the fix), and averaging."""
FUSIONS = tuple(ROWS)
GT_CLASSES = ("same object", "two objects", "object+background", "background")
ROW_PATTERNS = ("prior", "null", "saturated", "other")


def view_bin_labels() -> list[str]:
    """Printable names of `VIEW_BINS`."""
    labels = []
    for lo, hi in zip(VIEW_BINS, (*VIEW_BINS[1:], None), strict=True):
        labels.append(f"{lo}+" if hi is None else (str(lo) if hi == lo + 1 else f"{lo}-{hi - 1}"))
    return labels


# ---------------------------------------------------------------------------------------------
# One scene, one fusion mode.


@dataclass
class SceneRun:
    """What one pipeline run left behind, as the measurements need it."""

    probabilities: np.ndarray  # (N, T) fused p(y=1) per Gaussian
    views: np.ndarray  # (N,) accepted masks that saw each Gaussian
    primitive_ids: np.ndarray  # (N,) -1 = none
    relevance: np.ndarray  # (P, T) mean p per primitive
    pyx: np.ndarray  # (P, T+1) normalised conditionals
    log: MergeLog
    object_ids: np.ndarray  # (N,) final object per Gaussian, -1 none
    selected: np.ndarray  # distinct object ids answered for some task
    prior: float


def run_scene(case: SceneCase, models: Models, out_dir: Path, fusion: str) -> SceneRun:
    """Run the pipeline on `case` as `bfields eval`'s rows do, then replay steps 8-12 for the log."""
    gt_per_task = {t: sum(1 for g in case.ground_truth if g.task == t) for t in case.tasks}
    params = PipelineParams.model_validate(
        {
            "previews": False,
            "top_k": max(5, max(gt_per_task.values(), default=1)),
            **ROWS[fusion],
            "answer_min_peak": None,
        }
    )
    job = local_job(
        case.folder,
        out_dir / case.name / fusion,
        out_dir / "cache",
        case.tasks,
        params,
        models,
        cache_prefix=f"scenes/{case.name}/cache/",
    )
    spec, scene, runner = job.spec, job.scene, job.runner
    run_job(job, force=True)
    fused = get_arrays(spec.store, spec.key(FUSION_KEY))
    primitive_ids = load_primitives(spec, scene, runner)
    scores = primitive_scores(
        primitive_ids,
        fused["probabilities"],
        fused["logodds"],
        params,
        view_counts(spec, scene, runner, fused),
    )
    object_map = objects_from_primitives(
        scene.loaded.gaussians.means,
        primitive_ids,
        scores.pyx,
        params,
        scores.relevance,
        scores.evidence,
        lengths=scene.lengths,
        premerge=scores.premerge,
    )
    stored = read_result(spec.store, RESULT_PREFIX)
    if not np.array_equal(object_map.object_ids, stored.object_ids.astype(np.int64)):
        raise RuntimeError(f"{case.name}/{fusion}: the replayed clustering differs from the stored result")
    assert object_map.merges is not None
    (relevance,), _ = primitive_means(primitive_ids, [fused["probabilities"]])
    return SceneRun(
        probabilities=np.asarray(fused["probabilities"], dtype=np.float64),
        views=accepted_views(job),
        primitive_ids=primitive_ids,
        relevance=relevance,
        pyx=scores.pyx,
        log=object_map.merges,
        object_ids=object_map.object_ids,
        selected=np.unique(object_map.selection[object_map.selection >= 0]),
        prior=params.prior,
    )


def accepted_views(job: Job) -> np.ndarray:
    """(N,) how many accepted masks saw each Gaussian: the fuse stage's cached associations and
    stored OR-phi flags, counted like `fusion.bayes.count_views` (masks are exclusive, so at most
    one per frame)."""
    spec, scene = job.spec, job.scene
    accepted = get_arrays(spec.store, spec.key(ACCEPTED_KEY))
    offsets = np.concatenate([[0], np.cumsum(accepted["mask_counts"])])
    views = np.zeros(len(scene.loaded.gaussians), dtype=np.int64)
    for n, index in enumerate(accepted["frame_indices"]):
        vis = get_arrays(spec.cache_store, scene.keys.visibility_key(int(index)))
        flags = accepted["accepted"][offsets[n] : offsets[n + 1]]
        seen = vis["gaussian_ids"].astype(np.int64)[flags[vis["mask_ids"].astype(np.int64)]]
        views += np.bincount(seen, minlength=len(views))
    return views


# ---------------------------------------------------------------------------------------------
# Measurements.


@dataclass
class GroundTruthIds:
    """Per-Gaussian GT instance, which instances are objects, and each task's relevant Gaussians."""

    instance_ids: np.ndarray  # (N,)
    is_object: np.ndarray  # (I,) bool
    relevant: np.ndarray  # (N, T) bool: the Gaussian belongs to a GT object of the task
    granularity: list[str]  # per task: fine / coarse / absent


def ground_truth_ids(case: SceneCase, num_gaussians: int) -> GroundTruthIds:
    """The synthetic scene's per-Gaussian ground truth (`gt_gaussians.npz`), in the task order of
    the run (tasks.yaml)."""
    gt = load_ground_truth(case.folder)
    if len(gt.instance_ids) != num_gaussians:
        raise RuntimeError(f"{case.name}: {len(gt.instance_ids)} GT ids for {num_gaussians} Gaussians")
    by_text = {t.text: t for t in gt.tasks}
    relevant = np.zeros((num_gaussians, len(case.tasks)), dtype=bool)
    granularity = []
    for k, text in enumerate(case.tasks):
        task = by_text[text]
        relevant[:, k] = np.isin(gt.instance_ids, [o.instance_id for o in task.objects])
        granularity.append(task.granularity)
    return GroundTruthIds(
        instance_ids=gt.instance_ids,
        is_object=np.array([i.category == "object" for i in gt.instances]),
        relevant=relevant,
        granularity=granularity,
    )


def row_patterns(run: SceneRun) -> np.ndarray:
    """(P,) index into `ROW_PATTERNS` of each primitive's row: still the prior's conditional,
    all-null (every task below `LOW`), saturated (every task below `LOW` or above `SATURATED`,
    one above at least), or other."""
    prior_row = conditionals(np.full((1, run.relevance.shape[1]), run.prior))[0]
    at_prior = np.all(np.abs(run.pyx - prior_row) <= 1e-6, axis=1)
    low = run.relevance < LOW
    high = run.relevance > SATURATED
    null = np.all(low, axis=1)
    saturated = np.all(low | high, axis=1) & np.any(high, axis=1)
    return np.select([at_prior, null, saturated], [0, 1, 2], default=3)


def saturation(run: SceneRun, gt: GroundTruthIds) -> dict[str, Any]:
    """Saturated (Gaussian, task) pairs per accepted-view bin (relevant / irrelevant), and per
    task the share of observed Gaussians and of primitives saturated."""
    sat = run.probabilities > SATURATED
    bins = np.digitize(run.views, VIEW_BINS) - 1
    table: dict[str, list[int]] = {k: [0] * len(VIEW_BINS) for k in ("rel", "rel_sat", "irr", "irr_sat")}
    for b in range(len(VIEW_BINS)):
        rows = bins == b
        rel, s = gt.relevant[rows], sat[rows]
        table["rel"][b] += int(rel.sum())
        table["rel_sat"][b] += int((rel & s).sum())
        table["irr"][b] += int((~rel).sum())
        table["irr_sat"][b] += int((~rel & s).sum())
    observed = run.views > 0
    prim_sat = run.relevance > SATURATED
    prim_views = _primitive_median(run.primitive_ids, run.views, len(run.relevance))
    tasks = []
    for k in range(sat.shape[1]):
        rel = gt.relevant[:, k]
        tasks.append(
            {
                "granularity": gt.granularity[k],
                "gaussians_saturated_of_observed": _share(sat[observed, k]),
                "relevant_saturated": _share(sat[rel & observed, k]),
                "irrelevant_saturated_of_observed": _share(sat[~rel & observed, k]),
                "primitives_saturated": _share(prim_sat[:, k]),
            }
        )
    multi = prim_sat.sum(axis=1)
    return {
        "by_views": table,
        "tasks": tasks,
        "observed_gaussians": int(observed.sum()),
        "primitives": len(run.relevance),
        "primitives_saturated_any": int((multi >= 1).sum()),
        "primitives_saturated_two_plus": int((multi >= 2).sum()),
        "primitive_views_median": float(np.median(prim_views)) if len(prim_views) else 0.0,
        "row_patterns": np.bincount(row_patterns(run), minlength=len(ROW_PATTERNS)).tolist(),
    }


def _share(mask: np.ndarray) -> float | None:
    return float(mask.mean()) if mask.size else None


def _primitive_median(primitive_ids: np.ndarray, values: np.ndarray, num: int) -> np.ndarray:
    inside = primitive_ids >= 0
    order = np.argsort(primitive_ids[inside], kind="stable")
    ids, vals = primitive_ids[inside][order], values[inside][order]
    bounds = np.searchsorted(ids, np.arange(num + 1))
    return np.array([np.median(vals[bounds[p] : bounds[p + 1]]) for p in range(num)])


class Clusters:
    """Union-find over primitives carrying each cluster's Gaussians per GT instance, so every
    merge of the log can be classified by the dominant GT instance of its two sides."""

    def __init__(self, run: SceneRun, gt: GroundTruthIds) -> None:
        inside = run.primitive_ids >= 0
        num_p = len(run.relevance)
        self.counts = np.zeros((num_p, len(gt.is_object)), dtype=np.int64)
        np.add.at(self.counts, (run.primitive_ids[inside], gt.instance_ids[inside]), 1)
        self.parent = np.arange(num_p)
        self.is_object = gt.is_object
        self.first_cross: dict[int, str] = {}  # root -> stage of its first object-object join
        # Per root: summed p(y=1) and p(y|x) rows of its primitives and their number, so a join
        # can say whether both sides were saturated (uniform p(x): the AIB's node conditional is
        # the plain mean of its primitives' rows, the pre-merge's too).
        self.relevance = run.relevance.copy()
        self.rows = run.pyx.copy()
        self.size = np.ones(num_p)
        self.cross: list[dict[str, Any]] = []  # one record per object-object join

    def find(self, p: int) -> int:
        root = p
        while self.parent[root] != root:
            root = int(self.parent[root])
        while self.parent[p] != root:  # path compression
            self.parent[p], p = root, int(self.parent[p])
        return root

    def union(self, a: int, b: int, stage: str, cost: float = 0.0) -> str | None:
        """Join the clusters of primitives a and b (relative information loss `cost`); returns
        the GT class of the join (None when already one cluster). Object-object joins are
        recorded with how saturated both sides were (`cross`)."""
        ra, rb = self.find(a), self.find(b)
        if ra == rb:
            return None
        da, db = int(self.counts[ra].argmax()), int(self.counts[rb].argmax())
        oa, ob = bool(self.is_object[da]), bool(self.is_object[db])
        kind = (
            ("same object" if da == db else "two objects")
            if oa and ob
            else ("object+background" if oa or ob else "background")
        )
        earlier = {self.first_cross.pop(ra, None), self.first_cross.pop(rb, None)} - {None}
        first = "pre-merge" if "pre-merge" in earlier else ("AIB" if earlier else None)
        if first is None and kind == "two objects":
            first = stage
        if kind == "two objects":
            self.cross.append(self._join_record(ra, rb, stage, cost))
        keep, gone = min(ra, rb), max(ra, rb)
        self.parent[gone] = keep
        for table in (self.counts, self.relevance, self.rows, self.size):
            table[keep] += table[gone]
        if first is not None:
            self.first_cross[keep] = first
        return kind

    def _join_record(self, ra: int, rb: int, stage: str, cost: float) -> dict[str, Any]:
        """How alike the two sides of an object-object join were: the tasks each side's mean
        p(y=1) saturates (> `SATURATED`), and the L1 distance of their p(y|x) rows."""
        mean_a, mean_b = self.relevance[ra] / self.size[ra], self.relevance[rb] / self.size[rb]
        sat_a, sat_b = (
            set(np.flatnonzero(mean_a > SATURATED).tolist()),
            set(np.flatnonzero(mean_b > SATURATED).tolist()),
        )
        row_a, row_b = self.rows[ra] / self.size[ra], self.rows[rb] / self.size[rb]
        return {
            "stage": stage,
            "relative_cost": float(cost),
            "saturated_a": sorted(sat_a),
            "saturated_b": sorted(sat_b),
            "shared_saturated": len(sat_a & sat_b),
            "same_saturated_set": bool(sat_a) and sat_a == sat_b,
            "row_l1": float(np.abs(row_a - row_b).sum()),
            "max_p": [float(mean_a.max(initial=0.0)), float(mean_b.max(initial=0.0))],
            "null": [float(row_a[-1]), float(row_b[-1])],
            "primitives": [int(self.size[ra]), int(self.size[rb])],
        }


def merges(run: SceneRun, gt: GroundTruthIds) -> dict[str, Any]:
    """The pre-merge's unions by row pattern and GT class, the AIB's merges by relative cost and
    GT class, and the final objects that span two or more GT objects."""
    clusters = Clusters(run, gt)
    patterns = row_patterns(run)
    pre = {p: dict.fromkeys(GT_CLASSES, 0) for p in ROW_PATTERNS}
    for a, b in run.log.identical:
        kind = clusters.union(int(a), int(b), "pre-merge")
        if kind is not None:
            pre[ROW_PATTERNS[patterns[a]]][kind] += 1
    # AIB merges name pre-merge nodes; any primitive of a node stands for it in the union-find.
    representative = np.zeros(int(run.log.node_of_primitive.max(initial=-1)) + 1, dtype=np.int64)
    representative[run.log.node_of_primitive] = np.arange(len(run.log.node_of_primitive))
    relative = run.log.aib_costs / max(run.log.information, 1e-300)
    thresholds = {"0": 0.0, **{f"<{t:g}": t for t in NEAR_ZERO}, "all": np.inf}
    aib = {name: dict.fromkeys(GT_CLASSES, 0) for name in thresholds}
    for (a, b), cost in zip(run.log.aib_merges, relative, strict=True):
        kind = clusters.union(int(representative[a]), int(representative[b]), "AIB", float(cost))
        assert kind is not None  # the AIB only merges distinct clusters
        for name, limit in thresholds.items():
            if cost < limit or (limit == 0.0 and cost == 0.0):
                aib[name][kind] += 1
    return {
        "information": run.log.information,  # I(X;Y), nats: delta times it is the AIB's budget per merge
        "aib_nodes": int(run.log.node_of_primitive.max(initial=-1)) + 1,
        "pre_merge": pre,
        "aib": aib,
        "spanning": spanning_objects(run, gt, clusters),
        "object_object_joins": clusters.cross,
    }


def spanning_objects(run: SceneRun, gt: GroundTruthIds, clusters: Clusters) -> dict[str, Any]:
    """Per share in `SPAN_SHARES`: final objects holding at least that share of two or more GT
    objects' Gaussians; how many of them are answers, and where their first object-object join
    happened."""
    inside = run.object_ids >= 0
    num = int(run.object_ids.max(initial=-1)) + 1
    table = np.zeros((num, len(gt.is_object)), dtype=np.int64)
    np.add.at(table, (run.object_ids[inside], gt.instance_ids[inside]), 1)
    size = np.bincount(gt.instance_ids, minlength=len(gt.is_object))
    return {
        f"{share:g}": _spanning(run, clusters, (table / np.maximum(size, 1) >= share) & gt.is_object, num)
        for share in SPAN_SHARES
    }


def _spanning(run: SceneRun, clusters: Clusters, held: np.ndarray, num: int) -> dict[str, int]:
    out = {
        "objects": num,
        "spanning": 0,
        "spanning_answers": 0,
        "first_join_pre_merge": 0,
        "first_join_aib": 0,
    }
    selected = set(run.selected.tolist())
    for obj in np.flatnonzero(held.sum(axis=1) >= 2):
        out["spanning"] += 1
        out["spanning_answers"] += int(obj in selected)
        member = int(np.flatnonzero(run.object_ids == obj)[0])
        stage = clusters.first_cross.get(clusters.find(int(run.primitive_ids[member])))
        if stage == "pre-merge":
            out["first_join_pre_merge"] += 1
        elif stage == "AIB":
            out["first_join_aib"] += 1
    return out


# ---------------------------------------------------------------------------------------------
# Pooling and printing.


@dataclass
class SuiteTotals:
    """One (suite, fusion)'s numbers, summed over its scenes."""

    by_views: dict[str, list[int]] = field(default_factory=dict)
    tasks: list[dict[str, Any]] = field(default_factory=list)
    scenes: list[dict[str, Any]] = field(default_factory=list)

    def add(self, scene: str, sat: dict[str, Any], merged: dict[str, Any]) -> None:
        for key, values in sat["by_views"].items():
            old = self.by_views.setdefault(key, [0] * len(values))
            self.by_views[key] = [a + b for a, b in zip(old, values, strict=True)]
        self.tasks.extend({"scene": scene, **t} for t in sat["tasks"])
        summary = {k: v for k, v in sat.items() if k not in ("by_views", "tasks")}
        self.scenes.append({"scene": scene, **summary, **merged})

    def summed(self, *path: str) -> dict[str, Any]:
        """Sum of a nested dict of counts over the scenes (e.g. "pre_merge")."""
        total: dict[str, Any] = {}
        for scene in self.scenes:
            _add_nested(total, _dig(scene, path))
        return total


def _dig(doc: dict[str, Any], path: tuple[str, ...]) -> dict[str, Any]:
    for key in path:
        doc = doc[key]
    return doc


def _add_nested(into: dict[str, Any], more: dict[str, Any]) -> None:
    for key, value in more.items():
        if isinstance(value, dict):
            _add_nested(into.setdefault(key, {}), value)
        else:
            into[key] = into.get(key, 0) + value


def print_tables(suite: str, totals: dict[str, SuiteTotals]) -> None:
    """The suite's tables: saturation by views, by task granularity, rows, merges, outcome."""
    print(f"\n=== suite {suite!r}: {len(totals['bayes'].scenes)} scenes ===")
    print("\nShare of (Gaussian, task) pairs with p > 0.999, by accepted views (pairs in brackets):")
    header = f"{'views':>7} | " + " | ".join(f"{f + ' rel':>18} | {f + ' irrel':>20}" for f in totals)
    print(header)
    for b, label in enumerate(view_bin_labels()):
        cells = []
        for t in totals.values():
            v = t.by_views
            cells.append(
                f"{_pct(v['rel_sat'][b], v['rel'][b]):>18} | {_pct(v['irr_sat'][b], v['irr'][b]):>20}"
            )
        print(f"{label:>7} | " + " | ".join(cells))
    print("\nPer task (mean over the tasks of each granularity): saturated share of observed Gaussians,")
    print("of the task's GT Gaussians, of the others, and of primitives (mean p > 0.999):")
    for fusion, t in totals.items():
        for gran in sorted({x["granularity"] for x in t.tasks}):
            rows = [x for x in t.tasks if x["granularity"] == gran]
            means = [
                _mean([x[k] for x in rows])
                for k in (
                    "gaussians_saturated_of_observed",
                    "relevant_saturated",
                    "irrelevant_saturated_of_observed",
                    "primitives_saturated",
                )
            ]
            print(
                f"  {fusion:<8} {gran:<7} ({len(rows):>2} tasks): observed {means[0]}  relevant {means[1]}  "
                f"irrelevant {means[2]}  primitives {means[3]}"
            )
    print("\nPrimitive rows p(y|x): prior / null (all p < 0.001) / saturated pattern / other;")
    print("primitives saturated on >= 1 and >= 2 tasks:")
    for fusion, t in totals.items():
        rows = np.sum([s["row_patterns"] for s in t.scenes], axis=0)
        prims = sum(s["primitives"] for s in t.scenes)
        any_ = sum(s["primitives_saturated_any"] for s in t.scenes)
        two = sum(s["primitives_saturated_two_plus"] for s in t.scenes)
        print(
            f"  {fusion:<8} {prims:>6} primitives: "
            + "  ".join(f"{n} {c}" for n, c in zip(ROW_PATTERNS, rows, strict=True))
            + f"   saturated >=1: {any_}, >=2: {two}"
        )
    print("\nMerges by what they join in the ground truth (" + " / ".join(GT_CLASSES) + "):")
    for fusion, t in totals.items():
        pre = t.summed("pre_merge")
        print(f"  {fusion}: identical pre-merge (unions), by the rows' pattern:")
        for pattern in ROW_PATTERNS:
            counts = pre.get(pattern, {})
            print(f"    {pattern:<10} {_classes(counts)}")
        aib = t.summed("aib")
        print(f"  {fusion}: AIB merges by relative cost d/I(X;Y):")
        for name, counts in aib.items():
            print(f"    {name:<10} {_classes(counts)}")
    print(
        "\nObject-object joins: both sides saturated on a shared task / on the same task set; row L1 median:"
    )
    for fusion, t in totals.items():
        joins = [j for s in t.scenes for j in s["object_object_joins"]]
        for stage in ("pre-merge", "AIB"):
            js = [j for j in joins if j["stage"] == stage]
            shared = sum(j["shared_saturated"] > 0 for j in js)
            same = sum(j["same_saturated_set"] for j in js)
            l1 = f"{np.median([j['row_l1'] for j in js]):.3g}" if js else "-"
            print(
                f"  {fusion:<8} {stage:<9} {len(js):>4} joins: shared {shared:>4}, same set {same:>4}, L1 {l1}"
            )
    print("\nI(X;Y) of the AIB's input (nats; its budget per merge is aib_delta times it), per scene:")
    for fusion, t in totals.items():
        print(f"  {fusion:<8} " + "  ".join(f"{s['information']:.3f}" for s in t.scenes))
    for share in SPAN_SHARES:
        print(f"\nFinal objects spanning >= 2 GT objects (>= {share:.0%} of each):")
        for fusion, t in totals.items():
            s = t.summed("spanning", f"{share:g}")
            print(
                f"  {fusion:<8} {s['spanning']:>3} of {s['objects']} objects ({s['spanning_answers']} are answers); "
                f"first object-object join in the pre-merge: {s['first_join_pre_merge']}, in the AIB: {s['first_join_aib']}"
            )


def _pct(num: int, den: int) -> str:
    return f"{100 * num / den:5.1f}% ({den})" if den else "-"


def _mean(values: list[float | None]) -> str:
    kept = [v for v in values if v is not None]
    return f"{100 * float(np.mean(kept)):5.1f}%" if kept else "    -"


def _classes(counts: dict[str, int]) -> str:
    total = sum(counts.values())
    return f"{total:>5} = " + " / ".join(f"{counts.get(c, 0)}" for c in GT_CLASSES)


# ---------------------------------------------------------------------------------------------
# The figure.


def draw_figure(results: dict[str, dict[str, SuiteTotals]], path: Path) -> None:
    """One panel per suite: the saturated share of (Gaussian, task) pairs against accepted views,
    relevant and irrelevant pairs, full method and averaging."""
    from PIL import Image

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from plot_capture_effects import Chart  # sibling benchmark module, not a package

    colours = {
        ("bayes", "rel"): (31, 119, 180),
        ("bayes", "irr"): (214, 39, 40),
        ("average", "rel"): (120, 170, 220),
        ("average", "irr"): (250, 150, 140),
    }
    panels = []
    x = np.arange(len(VIEW_BINS), dtype=np.float64)
    for suite, totals in results.items():
        chart = Chart(
            title=f"{suite} suite: share of (Gaussian, task) pairs with p > {SATURATED}",
            xlabel="accepted views of the Gaussian",
            ylabel="share saturated",
            xlim=(-0.3, len(VIEW_BINS) - 0.7),
            ylim=(0.0, 1.0),
        )
        chart.axes([], [0.0, 0.2, 0.4, 0.6, 0.8, 1.0])
        bottom = chart.size[1] - chart.margin[3]
        for b, label in enumerate(view_bin_labels()):  # bin names as the x tick labels
            px = float(chart._fx(np.array(float(b))))
            chart.draw.line([px, bottom, px, bottom + 5], fill="black")
            chart.draw.text((px - 3 * len(label), bottom + 8), label, fill="black")
        for fusion, t in totals.items():
            if fusion == "per_view":  # the same fusion as 'bayes': the same saturation
                continue
            for kind, name in (("rel", "relevant"), ("irr", "irrelevant")):
                num, den = np.array(t.by_views[f"{kind}_sat"]), np.array(t.by_views[kind])
                share = np.where(den > 0, num / np.maximum(den, 1), np.nan)
                colour = colours[(fusion, kind)]
                chart.line(x, share, colour, width=3 if fusion == "bayes" else 2)
                ok = np.isfinite(share)
                chart.points(x[ok], share[ok], colour, r=3.5)
                label = "full method" if fusion == "bayes" else "averaging"
                chart.legend.append((f"{label}, {name} pairs", colour))
        chart.save(path.with_suffix(f".{suite}.tmp.png"))
        panels.append(chart.image)
        path.with_suffix(f".{suite}.tmp.png").unlink()
    canvas = Image.new("RGB", (sum(p.width for p in panels), max(p.height for p in panels)), "white")
    left = 0
    for panel in panels:
        canvas.paste(panel, (left, 0))
        left += panel.width
    path.parent.mkdir(parents=True, exist_ok=True)
    canvas.save(path, optimize=True)


# ---------------------------------------------------------------------------------------------


def write_outputs(results: dict[str, dict[str, SuiteTotals]], json_path: Path, figure: Path) -> None:
    """The JSON of every number and the figure, for the suites measured so far."""
    doc = {
        "what": "issue 23 item 1: saturation, identical pre-merge and zero-cost AIB merges (bench/merge_mechanism.py)",
        "saturated": SATURATED,
        "low": LOW,
        "near_zero_relative_costs": list(NEAR_ZERO),
        "view_bins": view_bin_labels(),
        "gt_classes": list(GT_CLASSES),
        "row_patterns": list(ROW_PATTERNS),
        "suites": {
            suite: {
                f: {"by_views": t.by_views, "scenes": t.scenes, "tasks": t.tasks} for f, t in totals.items()
            }
            for suite, totals in results.items()
        },
    }
    json_path.parent.mkdir(parents=True, exist_ok=True)
    json_path.write_text(json.dumps(doc, indent=1) + "\n")
    draw_figure(results, figure)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--suites", default="tabletop,capture")
    parser.add_argument("--scenes", type=int, default=5, help="public scenes per suite (1 to 5)")
    parser.add_argument("--suite-dir", type=Path, default=Path("build/suites"))
    parser.add_argument("--out", type=Path, default=Path("build/merge-mechanism"))
    parser.add_argument("--json", type=Path, default=Path("docs/research/merge-mechanism.json"))
    parser.add_argument("--figure", type=Path, default=Path("docs/research/merge-mechanism.png"))
    args = parser.parse_args(argv)
    models = load_models(None)
    results: dict[str, dict[str, SuiteTotals]] = {}
    for suite in args.suites.split(","):
        totals = {f: SuiteTotals() for f in FUSIONS}
        for case in prepare_scenes(args.suite_dir / suite, args.scenes, suite=suite):
            for fusion in FUSIONS:
                t0 = time.perf_counter()
                run = run_scene(case, models, args.out / suite, fusion)
                gt = ground_truth_ids(case, len(run.probabilities))
                totals[fusion].add(case.name, saturation(run, gt), merges(run, gt))
                print(f"  {case.name} {fusion}: {time.perf_counter() - t0:.0f} s", flush=True)
        results[suite] = totals
        print_tables(suite, totals)
        write_outputs(results, args.json, args.figure)  # after each suite: a cut-short run keeps it
    print(f"\nwrote {args.json} and {args.figure}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
