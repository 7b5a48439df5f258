"""METHOD steps 7-12 as one algorithm: primitives and their conditionals in, an object map out.

Each step is its own function (graph, AIB, pruning and selection, floater removal, geometry);
`objects_from_primitives` chains them and times each. The `cluster` stage and the evaluation
baselines both call it, so the method and the baselines share every step after the primitives.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import TypeVar

import numpy as np
import scipy.sparse as sp

from bayesian_fields_core.compute.threads import single_blas_thread
from bayesian_fields_core.geometry.obb import DEFAULT_MIN_THICKNESS, OrientedBox, minimum_obb
from bayesian_fields_core.objects.aib import aib
from bayesian_fields_core.objects.edges import MergedGraph, merge_identical, overlap_edges
from bayesian_fields_core.objects.knn_filter import statistical_outlier_mask
from bayesian_fields_core.objects.probabilities import conditionals, per_view_probabilities, primitive_means
from bayesian_fields_core.objects.scores import task_scores
from bayesian_fields_core.objects.select import prune_mask, top_k
from bayesian_fields_core.objects.timing import StepTimer
from bayesian_fields_core.params import PipelineParams
from bayesian_fields_core.scene.scale import SceneLengths

_T = TypeVar("_T")


@dataclass(frozen=True)
class MergeLog:
    """Which primitives steps 8-9 joined, and at what price: the record behind "why did these two
    neighbours end up in one object" (issue 23; `bench/merge_mechanism.py` reads it). Nothing in
    the map depends on it; it only keeps arrays the steps computed anyway.

    identical: (K1, 2) int64 primitive pairs (edges) the identical-vectors pre-merge tied (rows
    within `identical_tolerance`). node_of_primitive: (P,) int64 the pre-merge node of each
    primitive, the ids `aib_merges` use. aib_merges: (K2, 2) int64 node pairs in merge order (the
    lower id survives and names the union). aib_costs: (K2,) information loss `d_ij` of each
    merge, nats. information: `I(X;Y)` of the AIB's input, the normaliser of its stopping rule.
    """

    identical: np.ndarray
    node_of_primitive: np.ndarray
    aib_merges: np.ndarray
    aib_costs: np.ndarray
    information: float


@dataclass
class ObjectMap:
    """The clustered map before serialisation.

    object_ids: (N,) int64 object of each Gaussian, -1 = none (kNN-removed floaters of selected
    objects are none). probabilities: (C, T+1) p(y|object), null last. relevance: (C, T)
    p(y=1|object) when the caller supplied per-primitive relevance, else None. selection: (T, k) object
    ids per task, best first, -1 padded. boxes / centroids / sizes: per object, after filtering.
    ranking: (C, T) the score each task's objects were ranked by (mean log-odds with evidence,
    else `task_scores`), so a report can show the number that orders the ranks.
    merges: what the pre-merge and the AIB joined (`MergeLog`); None for maps not clustered here.
    """

    object_ids: np.ndarray
    primitive_ids: np.ndarray
    probabilities: np.ndarray
    relevance: np.ndarray | None
    selection: np.ndarray
    sizes: np.ndarray
    centroids: np.ndarray
    boxes: list[OrientedBox | None]
    counts: dict[str, int] = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)
    cpu_timings: dict[str, float] = field(default_factory=dict)
    ranking: np.ndarray | None = None
    merges: MergeLog | None = None

    @property
    def task_scores(self) -> np.ndarray:
        """(C, T) each task's score of each object (see `results.format.task_scores`)."""
        return task_scores(self.probabilities, self.relevance)


@dataclass
class PrimitiveScores:
    """Per-primitive inputs of the clustering: `pyx` (P, T+1) conditionals (null last), and for
    the selection score, `relevance` (P, T) mean fused probability and `evidence` (P, T) mean
    fused log-odds (None when the score does not use them). `premerge`: (P,) bool the primitives
    the identical pre-merge may join (None: all, the paper's rule)."""

    pyx: np.ndarray
    relevance: np.ndarray | None
    evidence: np.ndarray | None
    premerge: np.ndarray | None = None


@dataclass
class Selection:
    """Surviving objects after pruning, renumbered 0..K-1: `object_ids` (N,), `probabilities`
    (K, T+1), `relevance` (K, T) or None, `selection` (T, k) -1 padded, `clusters` before pruning,
    `ranking` (K, T) the score the selection ranked by."""

    object_ids: np.ndarray
    probabilities: np.ndarray
    relevance: np.ndarray | None
    selection: np.ndarray
    clusters: int
    ranking: np.ndarray


def primitive_scores(
    primitive_ids: np.ndarray,
    probabilities: np.ndarray,
    logodds: np.ndarray,
    params: PipelineParams,
    view_counts: np.ndarray | None = None,
) -> PrimitiveScores:
    """Step 7: p(y|x) of every primitive from its Gaussians' (N, T) fused `probabilities`, plus
    the relevance or evidence that `params.selection_score` ranks by (`logodds` (N, T)).

    With `aib_conditionals='per_view'` and `view_counts` (N,) (the Bayesian update's accepted
    views per Gaussian) the AIB's rows come from the per-view probabilities instead
    (`per_view_probabilities`), and only primitives no accepted view saw may be pre-merged;
    relevance and evidence stay the fused ones. Without view counts (the averaging ablation,
    whose probabilities are per-view means already) the fused rows are used."""
    with_evidence = params.selection_score == "evidence"
    per_view = params.aib_conditionals == "per_view" and view_counts is not None
    arrays = [probabilities] + ([logodds] if with_evidence else [])
    if per_view:
        assert view_counts is not None
        arrays += [
            per_view_probabilities(logodds, view_counts, params.prior),
            np.asarray(view_counts, dtype=np.float32)[:, None],
        ]
    means, _ = primitive_means(primitive_ids, arrays)
    relevance = None if params.selection_score == "conditional" else means[0]
    evidence = means[1] if with_evidence else None
    if per_view:
        return PrimitiveScores(
            conditionals(means[-2], params.null_mode), relevance, evidence, premerge=means[-1][:, 0] == 0
        )
    return PrimitiveScores(conditionals(means[0], params.null_mode), relevance, evidence)


def primitive_graph(
    means: np.ndarray,
    primitive_ids: np.ndarray,
    pyx: np.ndarray,
    gaussian_counts: np.ndarray,
    params: PipelineParams,
    lengths: SceneLengths,
    premerge: np.ndarray | None = None,
) -> tuple[np.ndarray, MergedGraph]:
    """Step 8: overlap edges (E, 2) between primitives, then identical neighbours merged.

    Boxes grow by `lengths.edge_padding` (scene units: the run's resolved lengths, never the raw
    parameters, so every caller pads alike). `premerge` (P,) bool: the primitives the pre-merge
    may join (None: all)."""
    edges = overlap_edges(means, primitive_ids, padding=lengths.edge_padding)
    weights = gaussian_counts if params.aib_px == "size" else None
    return edges, merge_identical(
        pyx, edges, atol=params.identical_tolerance, weights=weights, eligible=premerge
    )


def prune_and_select(
    object_of_primitive: np.ndarray,
    cluster_pyx: np.ndarray,
    primitive_ids: np.ndarray,
    gaussian_counts: np.ndarray,
    params: PipelineParams,
    *,
    relevance: np.ndarray | None = None,
    evidence: np.ndarray | None = None,
) -> Selection:
    """Steps 10-11: drop clusters below `prune_threshold` for every task, keep `top_k` per task.

    `relevance` (P, T) prunes and ranks by its Gaussian-weighted mean over each cluster; without
    it (the Clio-style baseline has no such quantity) the conditional `cluster_pyx` (C, T+1) is
    used. `evidence` (P, T) ranks instead when given. A task's answers are only objects at or
    above `prune_threshold` for that task: an object kept for another task is no answer to it."""
    cluster_mean = _cluster_mean_operator(object_of_primitive, gaussian_counts, len(cluster_pyx))
    relevance_all = None if relevance is None else cluster_mean @ relevance
    ranking = cluster_pyx if relevance_all is None else _with_null_column(relevance_all)
    keep = prune_mask(ranking, params.prune_threshold)
    relevant = ranking[:, :-1] >= params.prune_threshold  # (C, T): the per-task pruning rule
    if evidence is not None:
        ranking = _with_null_column(cluster_mean @ evidence)
    new_id = np.full(cluster_pyx.shape[0], -1, dtype=np.int64)  # pruned clusters become -1
    new_id[keep] = np.arange(int(keep.sum()))
    object_of_primitive = new_id[object_of_primitive]
    probabilities = cluster_pyx[keep]
    object_ids = np.where(primitive_ids >= 0, object_of_primitive[np.maximum(primitive_ids, 0)], -1)
    sizes = np.bincount(object_ids[object_ids >= 0], minlength=len(probabilities))
    candidates = relevant[keep] & (sizes >= params.min_object_gaussians)[:, None]
    selection = (
        top_k(ranking[keep], sizes, params.top_k, candidates=candidates)
        if len(probabilities)
        else np.full((cluster_pyx.shape[1] - 1, params.top_k), -1, dtype=np.int64)
    )
    return Selection(
        object_ids=object_ids,
        probabilities=probabilities,
        relevance=None if relevance_all is None else relevance_all[keep],
        selection=selection,
        clusters=int(cluster_pyx.shape[0]),
        ranking=ranking[keep][:, :-1],
    )


def members_by_object(object_ids: np.ndarray, num_objects: int) -> list[np.ndarray]:
    """Gaussian indices of each object 0..num_objects-1 (one stable sort, no per-object scan)."""
    order = np.argsort(object_ids, kind="stable")
    bounds = np.searchsorted(object_ids[order], np.arange(num_objects + 1))
    return [order[bounds[o] : bounds[o + 1]] for o in range(num_objects)]


def _per_object(fn: Callable[[np.ndarray], _T], members: list[np.ndarray]) -> list[_T]:
    """`fn` of each object's member indices, objects spread over the cores: the kNN queries,
    hull and compiled box search release the GIL, and objects are independent."""
    workers = min(len(members), os.cpu_count() or 1)
    if workers <= 1:
        return [fn(m) for m in members]
    with ThreadPoolExecutor(max_workers=workers) as pool:
        return list(pool.map(fn, members))


def remove_floaters(
    means: np.ndarray, object_ids: np.ndarray, selected: np.ndarray, num_objects: int, params: PipelineParams
) -> int:
    """Step 12a: the kNN filter on each selected object; removed Gaussians get object -1 in
    `object_ids` (in place). Returns how many were removed."""
    if not params.knn_filter:
        return 0
    members = members_by_object(object_ids, num_objects)
    filtered = [members[obj] for obj in selected if len(members[obj]) > 1]  # at most tasks x k
    keeps = _per_object(
        lambda m: statistical_outlier_mask(means[m], k=params.knn_k, std_ratio=params.knn_std_ratio), filtered
    )
    removed = 0
    for m, keep in zip(filtered, keeps, strict=True):
        object_ids[m[~keep]] = -1
        removed += int((~keep).sum())
    return removed


def object_geometry(
    means: np.ndarray,
    object_ids: np.ndarray,
    selected: np.ndarray,
    num_objects: int,
    box_min_side: float | None = None,
) -> tuple[np.ndarray, np.ndarray, list[OrientedBox | None]]:
    """Step 12b: (K,) sizes and (K, 3) centroids of every object, and the minimum oriented box
    of each selected one (None for the others). `box_min_side`: thinnest box side in scene
    units (`SceneLengths.box_min_side`; None: the box code's own floor)."""
    min_thickness = DEFAULT_MIN_THICKNESS if box_min_side is None else float(box_min_side)
    inside = object_ids >= 0
    sizes = np.bincount(object_ids[inside], minlength=num_objects)
    # bincount sums each axis in Gaussian order, as np.add.at did, ~10x faster
    centroids = (
        np.stack(
            [
                np.bincount(object_ids[inside], weights=means[inside, k], minlength=num_objects)
                for k in range(3)
            ],
            axis=1,
        )
        .reshape(num_objects, 3)
        .astype(np.float64)
    )  # an empty bincount is int64, even with weights
    centroids /= np.maximum(sizes, 1)[:, None]
    members = members_by_object(object_ids, num_objects)
    boxes: list[OrientedBox | None] = [None] * num_objects
    boxed = [obj for obj in selected if len(members[obj])]
    with single_blas_thread():  # many small products: BLAS's own threads only cost CPU here
        found = _per_object(
            lambda m: minimum_obb(means[m].astype(np.float64), min_thickness=min_thickness),
            [members[obj] for obj in boxed],
        )
    for obj, box in zip(boxed, found, strict=True):
        boxes[obj] = box
    return sizes, centroids, boxes


def objects_from_primitives(
    means: np.ndarray,
    primitive_ids: np.ndarray,
    pyx: np.ndarray,
    params: PipelineParams,
    relevance: np.ndarray | None = None,
    evidence: np.ndarray | None = None,
    *,
    lengths: SceneLengths,
    checkpoint: Callable[[], None] | None = None,
    premerge: np.ndarray | None = None,
) -> ObjectMap:
    """Steps 8-12 from primitives (N,) and their conditionals `pyx` (P, T+1) (shared by the
    method and the baselines); `relevance` / `evidence` as in `prune_and_select`; `lengths`: the
    run's lengths in scene units (edge padding, thinnest box side; `scene.scale.scene_lengths`).

    `checkpoint` is called between the steps (edges, AIB, select, kNN, boxes): the cluster stage
    passes its cancel check there, so a cancelled job stops within one step. `premerge` (P,)
    bool: the primitives the identical pre-merge may join (`PrimitiveScores.premerge`)."""
    check = checkpoint or (lambda: None)
    if pyx.shape[0] == 0:
        return empty_object_map(len(means), primitive_ids, pyx.shape[1], params.top_k)
    timer = StepTimer()
    with timer("edges"):
        counts = np.bincount(primitive_ids[primitive_ids >= 0], minlength=pyx.shape[0]).astype(np.float64)
        edges, merged = primitive_graph(means, primitive_ids, pyx, counts, params, lengths, premerge)
    check()
    with timer("aib"):
        clustering = aib(merged.pyx, merged.edges, params.aib_delta, weights=merged.weights)
    check()
    with timer("select"):
        chosen = prune_and_select(
            clustering.labels[merged.labels],
            clustering.pyx,
            primitive_ids,
            counts,
            params,
            relevance=relevance,
            evidence=evidence,
        )
    object_ids, num_objects = chosen.object_ids, len(chosen.probabilities)
    selected = np.unique(chosen.selection[chosen.selection >= 0])
    check()
    with timer("knn"):
        removed = remove_floaters(means, object_ids, selected, num_objects, params)
    check()
    with timer("boxes"):
        sizes, centroids, boxes = object_geometry(
            means, object_ids, selected, num_objects, lengths.box_min_side
        )
    return ObjectMap(
        object_ids=object_ids,
        primitive_ids=primitive_ids,
        probabilities=chosen.probabilities,
        relevance=chosen.relevance,
        selection=chosen.selection,
        sizes=sizes,
        centroids=centroids,
        boxes=boxes,
        counts=_counts(
            int(pyx.shape[0]),
            int(merged.pyx.shape[0]),
            int(edges.shape[0]),
            chosen.clusters,
            num_objects,
            len(selected),
            removed,
        ),
        timings=timer.seconds,
        cpu_timings=timer.cpu_seconds,
        ranking=chosen.ranking,
        merges=MergeLog(
            identical=merged.identical,
            node_of_primitive=merged.labels,
            aib_merges=clustering.merges,
            aib_costs=clustering.costs,
            information=clustering.information,
        ),
    )


def _counts(
    primitives: int, nodes: int, edges: int, clusters: int, objects: int, selected: int, removed: int
) -> dict[str, int]:
    return {
        "primitives": primitives,
        "nodes_after_identical_merge": nodes,
        "edges": edges,
        "clusters": clusters,
        "objects": objects,
        "selected_objects": selected,
        "knn_removed_gaussians": removed,
    }


def empty_object_map(n_gaussians: int, primitive_ids: np.ndarray, n_columns: int, k: int) -> ObjectMap:
    """The map of a scene where every mask was rejected: no objects, so no task has a match.

    A legitimate outcome (e.g. a task list unrelated to the scene), not an error: the result
    still records the tasks, with empty selections.
    """
    return ObjectMap(
        object_ids=np.full(n_gaussians, -1, dtype=np.int64),
        primitive_ids=primitive_ids,
        probabilities=np.zeros((0, n_columns)),
        relevance=np.zeros((0, n_columns - 1)),
        selection=np.full((n_columns - 1, k), -1, dtype=np.int64),
        sizes=np.zeros(0, dtype=np.int64),
        centroids=np.zeros((0, 3)),
        boxes=[],
        counts=_counts(0, 0, 0, 0, 0, 0, 0),
        timings={},
    )


def _cluster_mean_operator(
    cluster_of_primitive: np.ndarray, gaussian_counts: np.ndarray, num_clusters: int
) -> sp.csr_matrix:
    """(C, P) sparse operator: times a per-primitive (P, T) mean it gives each cluster's
    Gaussian-weighted mean, i.e. the mean over all the cluster's Gaussians."""
    weight = np.bincount(cluster_of_primitive, weights=gaussian_counts, minlength=num_clusters)
    share = gaussian_counts / np.maximum(weight[cluster_of_primitive], 1e-12)
    return sp.csr_matrix(
        (share, (cluster_of_primitive, np.arange(len(cluster_of_primitive)))),
        shape=(num_clusters, len(cluster_of_primitive)),
    )


def _with_null_column(task_scores: np.ndarray) -> np.ndarray:
    """(C, T) task scores as the (C, T+1) table `prune_mask` / `top_k` read; the null column is
    never ranked, so its value does not matter."""
    return np.concatenate([task_scores, np.zeros((len(task_scores), 1))], axis=1)
