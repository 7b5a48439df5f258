"""The two baselines of the evaluation table, run on the very same masks and embeddings.

- Semantic-Gaussians style: each Gaussian averages the CLIP embeddings of the masks it is seen
  through; a Gaussian takes the task with the best cosine score when that score passes a
  threshold ("best label"); the Gaussians of a task are split into spatially connected objects.
- Clio style: the same primitives as ours (every mask, no OR-phi), each primitive's embedding is
  the mean of its Gaussians' averaged embeddings, p(y|x) is built from its cosine scores by Clio's
  rules (a fixed-score null task, each primitive's top two scores kept: `clio_rows.py`), then the
  same AIB, pruning and selection as the method.

Both read the per-frame perception and visibility caches a method run left behind, so the
comparison isolates the fusion and clustering, not the perception.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from bayesian_fields_core.eval.clio_rows import clio_conditionals, clio_null_score
from bayesian_fields_core.job.job_scene import JobScene
from bayesian_fields_core.job.spec import JobSpec
from bayesian_fields_core.job.store import get_arrays
from bayesian_fields_core.objects.clustering import ObjectMap, objects_from_primitives
from bayesian_fields_core.objects.primitives import PrimitiveBuilder
from bayesian_fields_core.objects.probabilities import membership_matrix


@dataclass
class BaselineParams:
    """Baseline knobs.

    best_label_threshold: minimum cosine for a Gaussian to take a label (None = midpoint of the
    calibrated mu0 and mu1). component_radius: neighbour distance linking Gaussians of one object,
    metres. clio_null_score: cosine score given to Clio's null task (None = Clio's
    threshold carried to the calibration, `clio_rows.clio_null_score`).
    """

    best_label_threshold: float | None = None
    component_radius: float = 0.03
    min_component_size: int = 20
    clio_null_score: float | None = None


def averaged_embeddings(spec: JobSpec, scene: JobScene) -> tuple[np.ndarray, np.ndarray, PrimitiveBuilder]:
    """(N, D) mean mask embedding per Gaussian (L2-normalised), (N,) view counts, and the
    primitives built from every mask (no rejection), in one pass over the cached frames."""
    store = spec.cache_store
    n = len(scene.loaded.gaussians)
    sums: np.ndarray | None = None
    counts = np.zeros(n, dtype=np.int64)
    builder = PrimitiveBuilder(n)
    for index, _frame in scene.selected_frames:
        emb = get_arrays(store, scene.keys.perception_key(index))["embeddings"].astype(np.float32)
        vis = get_arrays(store, scene.keys.visibility_key(index))
        g = vis["gaussian_ids"].astype(np.int64)
        m = vis["mask_ids"].astype(np.int64)
        if sums is None:
            sums = np.zeros((n, emb.shape[1]), dtype=np.float32)
        if len(emb):
            sums[g] += emb[m]
            counts[g] += 1
        builder.add_frame(g, m, np.ones(len(emb), dtype=bool))
    if sums is None:
        raise ValueError("no frames")
    norms = np.linalg.norm(sums, axis=1, keepdims=True)
    return sums / np.maximum(norms, 1e-12), counts, builder


def semantic_gaussians(
    spec: JobSpec, scene: JobScene, text: np.ndarray, params: BaselineParams, mu0: float, mu1: float
) -> ObjectMap:
    """Best-label thresholding of per-Gaussian averaged embeddings, objects = connected parts."""
    means = scene.loaded.gaussians.means
    emb, counts, _ = averaged_embeddings(spec, scene)
    scores = emb @ text.T  # (N, T)
    threshold = params.best_label_threshold if params.best_label_threshold is not None else 0.5 * (mu0 + mu1)
    best = np.argmax(scores, axis=1)
    labelled = (counts > 0) & (scores[np.arange(len(best)), best] >= threshold)
    idx = np.flatnonzero(labelled)
    # Connected parts among Gaussians sharing a label: radius graph restricted to same-label pairs.
    pairs = cKDTree(means[idx]).query_pairs(params.component_radius, output_type="ndarray")
    pairs = pairs[best[idx[pairs[:, 0]]] == best[idx[pairs[:, 1]]]]
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(idx), len(idx)))
    _, comp = connected_components(graph, directed=False)
    sizes = np.bincount(comp)
    big = sizes[comp] >= params.min_component_size
    comp_ids = np.unique(comp[big], return_inverse=True)[1]
    object_ids = np.full(len(means), -1, dtype=np.int64)
    object_ids[idx[big]] = comp_ids
    n_obj = int(comp_ids.max(initial=-1)) + 1
    members = membership_matrix(object_ids, n_obj)
    obj_sizes = np.asarray(members.sum(axis=1)).reshape(-1)
    obj_scores = np.asarray(members @ scores) / np.maximum(obj_sizes, 1)[:, None]
    obj_label = np.zeros(n_obj, dtype=np.int64)
    obj_label[object_ids[idx[big]]] = best[idx[big]]
    # An object answers only the task it is labelled with; its score ranks it among that task's.
    table = np.zeros((n_obj, text.shape[0] + 1))
    table[np.arange(n_obj), obj_label] = obj_scores[np.arange(n_obj), obj_label]
    return _finish(means, object_ids, table, obj_sizes, spec.params.top_k)


def clio_style(
    spec: JobSpec, scene: JobScene, text: np.ndarray, params: BaselineParams, mu0: float, mu1: float
) -> ObjectMap:
    """Clio's AIB on its cosine-built p(y|x) over the same primitives (no Bayesian fusion)."""
    means = scene.loaded.gaussians.means
    emb, counts, builder = averaged_embeddings(spec, scene)
    primitive_ids = builder.primitive_ids.astype(np.int64)
    n_prim = int(primitive_ids.max(initial=-1)) + 1
    members = membership_matrix(primitive_ids, n_prim)
    prim_emb = np.asarray(members @ emb)
    prim_emb /= np.maximum(np.linalg.norm(prim_emb, axis=1, keepdims=True), 1e-12)
    # Clio's rows (`clio_rows.py`): cosines clipped at 0, a fixed-score null task, only each
    # primitive's top two scores kept; the null score is Clio's threshold carried to this calibration.
    null = params.clio_null_score if params.clio_null_score is not None else clio_null_score(mu0, mu1)
    pyx = clio_conditionals(prim_emb @ text.T, null)
    # Clio has no floater filter: the baseline keeps every Gaussian of its objects.
    return objects_from_primitives(
        means, primitive_ids, pyx, spec.params.model_copy(update={"knn_filter": False}), lengths=scene.lengths
    )


def _finish(
    means: np.ndarray, object_ids: np.ndarray, table: np.ndarray, sizes: np.ndarray, k: int
) -> ObjectMap:
    """Selection and boxes for a baseline that produced objects directly."""
    from bayesian_fields_core.geometry.obb import OrientedBox, minimum_obb
    from bayesian_fields_core.objects.select import top_k

    selection = top_k(table, sizes, k) if len(table) else np.full((table.shape[1] - 1, k), -1, dtype=np.int64)
    centroids = np.zeros((len(table), 3))
    np.add.at(centroids, object_ids[object_ids >= 0], means[object_ids >= 0])
    centroids /= np.maximum(sizes, 1)[:, None]
    boxes: list[OrientedBox | None] = [None] * len(table)
    for obj in np.unique(selection[selection >= 0]):
        boxes[obj] = minimum_obb(means[object_ids == obj].astype(np.float64))
    return ObjectMap(
        object_ids=object_ids,
        primitive_ids=np.full(len(object_ids), -1, dtype=np.int64),
        probabilities=table,
        relevance=None,
        selection=selection,
        sizes=sizes,
        centroids=centroids,
        boxes=boxes,
        counts={"objects": len(table)},
    )
