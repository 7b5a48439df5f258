"""Stage 3, `cluster`: primitives -> p(y|x) -> edges -> AIB -> prune -> top-k -> kNN -> result.

METHOD steps 6-12. Runs on the CPU queue: it reads the fused probabilities, the per-mask
acceptance flags and the cached mask-to-Gaussian associations, and writes the result.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse as sp

from ..context import JobContext
from ..objects.aib import aib
from ..objects.edges import merge_identical, overlap_edges
from ..objects.knn_filter import statistical_outlier_mask
from ..objects.obb import OrientedBox, minimum_obb
from ..objects.primitives import PrimitiveBuilder
from ..objects.probabilities import primitive_probabilities, primitive_relevance
from ..objects.select import prune_mask, top_k
from ..params import PipelineParams
from ..results.format import Result, SelectedObject, task_scores
from ..store import get_arrays
from .fuse import ACCEPTED_KEY, FUSION_KEY
from .markers import write_marker

RESULT_PREFIX = "result/"


@dataclass
class ObjectMap:
    """The clustered map before serialisation.

    object_ids: (N,) int64 object of each Gaussian, -1 = none (kNN-removed floaters of selected
    objects are none). probabilities: (C, T+1) p(y|object), null last. relevance: (C, T)
    p(y=1|object) when the caller supplied per-primitive relevance, else None. selection: (T, k) object
    ids per task, best first, -1 padded. boxes / centroids / sizes: per object, after filtering.
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

    @property
    def task_scores(self) -> np.ndarray:
        """(C, T) each task's score of each object (see `results.format.task_scores`)."""
        return task_scores(self.probabilities, self.relevance)


def objects_from_primitives(
    means: np.ndarray,
    primitive_ids: np.ndarray,
    pyx: np.ndarray,
    params: PipelineParams,
    relevance: np.ndarray | None = None,
    evidence: np.ndarray | None = None,
) -> ObjectMap:
    """Steps 8-12 from primitives and their conditionals (shared by the method and baselines).

    `relevance` (P, T) is each primitive's unnormalised p(y=1|x); with `selection_score =
    'relevance'` objects are pruned and ranked by its Gaussian-weighted mean over the object.
    Without it (the Clio-style baseline, which has no such quantity) the conditional is used.
    `evidence` (P, T), each primitive's mean fused log-odds, ranks objects instead when given.
    """
    if pyx.shape[0] == 0:
        return _empty_object_map(len(means), primitive_ids, pyx.shape[1], params.top_k)
    timings: dict[str, float] = {}
    t = time.perf_counter()
    gaussian_counts = np.bincount(primitive_ids[primitive_ids >= 0], minlength=pyx.shape[0]).astype(
        np.float64
    )
    edges = overlap_edges(means, primitive_ids, padding=params.edge_padding)
    weights = gaussian_counts if params.aib_px == "size" else None
    merged = merge_identical(pyx, edges, atol=params.identical_tolerance, weights=weights)
    timings["edges"] = time.perf_counter() - t
    t = time.perf_counter()
    clustering = aib(merged.pyx, merged.edges, params.aib_delta, weights=merged.weights)
    timings["aib"] = time.perf_counter() - t

    t = time.perf_counter()
    object_of_primitive = clustering.labels[merged.labels]
    raw_pyx = clustering.pyx
    cluster_mean = _cluster_mean_operator(object_of_primitive, gaussian_counts, len(raw_pyx))
    object_relevance_all = None if relevance is None else cluster_mean @ relevance
    ranking = raw_pyx if object_relevance_all is None else _with_null_column(object_relevance_all)
    keep = prune_mask(ranking, params.prune_threshold)
    if evidence is not None:
        ranking = _with_null_column(cluster_mean @ evidence)
    # Renumber surviving objects 0..K-1; pruned objects become -1.
    new_id = np.full(raw_pyx.shape[0], -1, dtype=np.int64)
    new_id[keep] = np.arange(int(keep.sum()))
    object_of_primitive = new_id[object_of_primitive]
    probabilities = raw_pyx[keep]
    object_relevance = None if object_relevance_all is None else object_relevance_all[keep]
    object_ids = np.where(primitive_ids >= 0, object_of_primitive[np.maximum(primitive_ids, 0)], -1)
    sizes = np.bincount(object_ids[object_ids >= 0], minlength=len(probabilities))
    selection = (
        top_k(ranking[keep], sizes, params.top_k, candidates=sizes >= params.min_object_gaussians)
        if len(probabilities)
        else np.full((raw_pyx.shape[1] - 1, params.top_k), -1, dtype=np.int64)
    )
    timings["select"] = time.perf_counter() - t

    t = time.perf_counter()
    selected = np.unique(selection[selection >= 0])
    order = np.argsort(object_ids, kind="stable")
    bounds = np.searchsorted(object_ids[order], np.arange(len(probabilities) + 1))
    removed = 0
    for obj in selected:  # a loop over selected objects (at most tasks x k), not Gaussians
        members = order[bounds[obj] : bounds[obj + 1]]
        if params.knn_filter and len(members) > 1:
            keep_pts = statistical_outlier_mask(
                means[members], k=params.knn_k, std_ratio=params.knn_std_ratio
            )
            object_ids[members[~keep_pts]] = -1
            removed += int((~keep_pts).sum())
    timings["knn"] = time.perf_counter() - t

    t = time.perf_counter()
    sizes = np.bincount(object_ids[object_ids >= 0], minlength=len(probabilities))
    centroids = np.zeros((len(probabilities), 3))
    np.add.at(centroids, object_ids[object_ids >= 0], means[object_ids >= 0])
    centroids /= np.maximum(sizes, 1)[:, None]
    order = np.argsort(object_ids, kind="stable")
    bounds = np.searchsorted(object_ids[order], np.arange(len(probabilities) + 1))
    boxes: list[OrientedBox | None] = [None] * len(probabilities)
    for obj in selected:
        members = order[bounds[obj] : bounds[obj + 1]]
        if len(members):
            boxes[obj] = minimum_obb(means[members].astype(np.float64))
    timings["boxes"] = time.perf_counter() - t
    return ObjectMap(
        object_ids=object_ids,
        primitive_ids=primitive_ids,
        probabilities=probabilities,
        relevance=object_relevance,
        selection=selection,
        sizes=sizes,
        centroids=centroids,
        boxes=boxes,
        counts={
            "primitives": int(pyx.shape[0]),
            "nodes_after_identical_merge": int(merged.pyx.shape[0]),
            "edges": int(edges.shape[0]),
            "clusters": int(raw_pyx.shape[0]),
            "objects": int(len(probabilities)),
            "selected_objects": int(len(selected)),
            "knn_removed_gaussians": removed,
        },
        timings=timings,
    )


def _empty_object_map(n_gaussians: int, primitive_ids: np.ndarray, n_columns: int, k: int) -> ObjectMap:
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
        counts={
            "primitives": 0,
            "nodes_after_identical_merge": 0,
            "edges": 0,
            "clusters": 0,
            "objects": 0,
            "selected_objects": 0,
            "knn_removed_gaussians": 0,
        },
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


def build_primitives(ctx: JobContext) -> np.ndarray:
    """Replay the primitive rule over the frames with the masks OR-phi accepted (step 6)."""
    scene_store = ctx.scene_store
    assert scene_store is not None
    accepted = get_arrays(ctx.store, ctx.job_key(ACCEPTED_KEY))
    offsets = np.concatenate([[0], np.cumsum(accepted["mask_counts"])])
    builder = PrimitiveBuilder(len(ctx.scene().gaussians))
    for n, index in enumerate(accepted["frame_indices"]):
        vis = get_arrays(scene_store, ctx.visibility_key(int(index)))
        builder.add_frame(
            vis["gaussian_ids"].astype(np.int64),
            vis["mask_ids"].astype(np.int64),
            accepted["accepted"][offsets[n] : offsets[n + 1]],
        )
        ctx.check_cancel()
    return builder.primitive_ids


def run(ctx: JobContext) -> dict[str, Any]:
    from ..results.writer import write_result

    t0 = time.perf_counter()
    timings: dict[str, float] = {}
    gaussians = ctx.scene().gaussians
    fused = get_arrays(ctx.store, ctx.job_key(FUSION_KEY))
    probs = fused["probabilities"]
    ctx.progress("cluster", 0.05)

    t = time.perf_counter()
    primitive_ids = build_primitives(ctx)
    timings["primitives"] = time.perf_counter() - t
    ctx.progress("cluster", 0.3)

    t = time.perf_counter()
    pyx = primitive_probabilities(primitive_ids, probs, null_mode=ctx.params.null_mode)
    score = ctx.params.selection_score
    relevance = evidence = None
    if score != "conditional":
        relevance, _ = primitive_relevance(primitive_ids, probs, pyx.shape[0])
    if score == "evidence":
        evidence, _ = primitive_relevance(primitive_ids, fused["logodds"], pyx.shape[0])
    timings["probabilities"] = time.perf_counter() - t
    object_map = objects_from_primitives(gaussians.means, primitive_ids, pyx, ctx.params, relevance, evidence)
    timings.update(object_map.timings)
    ctx.progress("cluster", 0.8)

    t = time.perf_counter()
    stage_timings = _stage_timings(ctx)
    stage_timings["cluster"] = time.perf_counter() - t0
    result = build_result(ctx, object_map, stage_timings)
    sizes = write_result(
        ctx.store,
        ctx.job_key(RESULT_PREFIX),
        result,
        gaussians=ctx.scene().splat_frame_gaussians() if ctx.params.export_ply else None,
        export_ply=ctx.params.export_ply,
        frames=ctx.scene().frames,
        preview_max_side=ctx.params.preview_max_side if ctx.params.previews else None,
        scene=_scene_record(ctx),
    )
    timings["write"] = time.perf_counter() - t
    ctx.progress("cluster", 1.0)
    return write_marker(
        ctx,
        "cluster",
        {
            "seconds": time.perf_counter() - t0,
            "timings": timings,
            "counts": object_map.counts,
            "result_bytes": sizes,
        },
    )


def _scene_record(ctx: JobContext) -> dict[str, Any]:
    """Where the result's scene lives, for `bfields view`: a local folder (CLI) or a store prefix."""
    scene = ctx.scene()
    return {
        "folder": str(Path(ctx.scene_dir).resolve()) if ctx.scene_dir is not None else None,
        "store_prefix": None if ctx.scene_dir is not None else f"{ctx.scene_prefix}input/",
        "num_gaussians": len(scene.gaussians),
        "num_frames": len(scene.frames),
    }


def build_result(ctx: JobContext, object_map: ObjectMap, timings: dict[str, float]) -> Result:
    """The serialisable result: id maps, probability table, per-task selections, provenance.

    The map is computed in the cameras' frame (where the loader put the Gaussians); boxes and
    centroids are reported in the splat file's frame and, when the loader applied a transform,
    also in the capture frame (`SelectedObject.capture_*`).
    """
    scene = ctx.scene()
    to_capture = scene.splat_to_capture
    to_splat = None if to_capture is None else to_capture.inverse()
    selections: dict[str, list[SelectedObject]] = {}
    scores = object_map.task_scores
    for t, task in enumerate(ctx.tasks):
        chosen = []
        for obj in object_map.selection[t]:
            box = object_map.boxes[obj] if obj >= 0 else None
            if obj < 0 or box is None or object_map.sizes[obj] == 0:
                continue
            centroid = object_map.centroids[obj]
            chosen.append(
                SelectedObject(
                    object_id=int(obj),
                    probability=float(scores[obj, t]),
                    num_gaussians=int(object_map.sizes[obj]),
                    centroid=centroid if to_splat is None else to_splat.points(centroid),
                    box=box if to_splat is None else to_splat.box(box),
                    capture_centroid=None if to_splat is None else centroid,
                    capture_box=None if to_splat is None else box,
                )
            )
        selections[task] = chosen
    return Result(
        tasks=list(ctx.tasks),
        object_ids=object_map.object_ids,
        probabilities=object_map.probabilities.astype(np.float32),
        relevance=None if object_map.relevance is None else object_map.relevance.astype(np.float32),
        selections=selections,
        primitive_ids=object_map.primitive_ids if ctx.params.store_primitive_ids else None,
        parameters=ctx.params.model_dump(mode="json"),
        models=ctx.models.model_ids,
        timings_s=timings,
        num_primitives=int(object_map.counts.get("primitives", 0)),
        splat_to_capture=None if to_capture is None else to_capture.matrix,
        layout=scene.layout,
    )


def _stage_timings(ctx: JobContext) -> dict[str, float]:
    from .markers import STAGES, is_done, read_marker

    return {
        stage: float(read_marker(ctx, stage).get("seconds", 0.0))
        for stage in STAGES[: STAGES.index("cluster")]
        if is_done(ctx, stage)
    }
