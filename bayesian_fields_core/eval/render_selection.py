"""The "w/o PE" ablation's selection: rank objects by the CLIP vector of a rendered view of each.

The paper's alternative to probability-based extraction (its Sec. 4.4 and Table 3, row "PE"):
"compute a CLIP vector for each object by rendering a view of the object (chosen as the training
pose with highest visibility of the object) from the 3D Gaussian Splat and selecting objects based
on highest cosine score to a text embedding of the task". Here, as docs/research/ablation-decision.md
fixes it, the map is the full method's (same fusion, primitives, clustering, kNN filter) and only
the selection differs:

1. visibility (`visible_counts`): in every training frame, the Gaussians the fuse stage found
   visible (centre in the image, in front of the camera, not occluded against the rendered
   depth): its cached pairs, read back (every Gaussian on a pixel some mask covers; the
   segmenters label nearly every pixel), or, when the cache lacks a frame, the same test with
   every pixel labelled (`visible_gaussians`), counted per object;
2. best view (`best_views`): for each object the frame with the most visible Gaussians of it
   (ties: the earliest frame); an object no frame sees is not selectable;
3. crop (`object_crops`): that frame rendered from the splat, the object's pixels kept (its
   rendered footprint: where the object's Gaussians rendered alone are opaque and not behind the
   whole splat's depth, so occluders cut it, `object_footprint`), the rest black, cropped to the
   footprint's box as perception crops a segment (`perception.crops.mask_crops`, padding and
   square window as there);
4. ranking (`rank_by_cosine`): every crop embedded with the run's image encoder (in the realistic
   regime its wrapped encoder, so the scores go through the regime's transform like the masks'),
   and each task takes its `n` objects of highest cosine to the task's text embedding, `n` being
   the number of answers the full method gives that task (so the row differs only in the ranking).

Only the renders and encodes are this row's own cost: the map comes from the full row's run.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from bayesian_fields_core.fusion.visibility import centre_columns, mask_associations
from bayesian_fields_core.geometry.obb import OrientedBox
from bayesian_fields_core.job.store import get_arrays
from bayesian_fields_core.objects.clustering import object_geometry, remove_floaters
from bayesian_fields_core.params import PipelineParams
from bayesian_fields_core.perception.crops import mask_crops
from bayesian_fields_core.perception.encoder import Encoder
from bayesian_fields_core.render import GaussianRenderer
from bayesian_fields_core.scene.types import Gaussians


def visible_gaussians(
    centres: torch.Tensor,
    frame: Any,
    depth: np.ndarray | torch.Tensor,
    *,
    depth_tolerance: float,
    relative_tolerance: float,
    near: float,
) -> np.ndarray:
    """(n,) int64 ids of the Gaussians visible in `frame`, by the fuse stage's own test.

    centres: (3, N) float64 (`visibility.centre_columns`); depth: (H, W) the frame's depth as the
    fuse stage uses it (`stages.fuse.frame_depth`). Every pixel counts as labelled, so visibility
    does not depend on what the segmenter found in the frame.
    """
    labels = torch.zeros((frame.height, frame.width), dtype=torch.int32, device=centres.device)
    gids, _ = mask_associations(
        centres,
        frame.K,
        frame.world_to_camera,
        frame.width,
        frame.height,
        depth,
        labels,
        depth_tolerance=depth_tolerance,
        relative_tolerance=relative_tolerance,
        near=near,
    )
    return gids.cpu().numpy()


def visible_counts(
    object_ids: np.ndarray, visible_per_frame: Sequence[np.ndarray], num_objects: int
) -> np.ndarray:
    """(F, O) int64: in each frame, how many of each object's Gaussians are visible.

    object_ids: (N,) object of each Gaussian (-1 none); visible_per_frame: F arrays of Gaussian ids.
    """
    object_ids = np.asarray(object_ids, dtype=np.int64)
    counts = np.zeros((len(visible_per_frame), num_objects), dtype=np.int64)
    for f, gids in enumerate(visible_per_frame):
        objs = object_ids[np.asarray(gids, dtype=np.int64)]
        counts[f] = np.bincount(objs[objs >= 0], minlength=num_objects)[:num_objects]
    return counts


def best_views(counts: np.ndarray) -> np.ndarray:
    """(O,) int64 frame index with the most visible Gaussians of each object, -1 when no frame
    sees any of them (such an object is not selectable); ties go to the earliest frame."""
    counts = np.asarray(counts)
    if counts.shape[0] == 0:
        return np.full(counts.shape[1], -1, dtype=np.int64)
    best = counts.argmax(axis=0).astype(np.int64)  # argmax: first of equal maxima
    best[counts.max(axis=0) <= 0] = -1
    return best


def to_uint8(rgb: np.ndarray) -> np.ndarray:
    """(H, W, 3) float colours in [0, 1] -> uint8, as the perception stage reads images."""
    return np.clip(np.rint(np.asarray(rgb) * 255.0), 0, 255).astype(np.uint8)


def object_crop(image: np.ndarray, footprint: np.ndarray) -> np.ndarray | None:
    """The object's crop (h, w, 3) uint8: its `footprint` (H, W) bool pixels of `image` (H, W, 3)
    uint8, the rest black, cut to the footprint's box grown and squared as perception crops a
    segment (`mask_crops`); None for an empty footprint (nothing to embed)."""
    if not footprint.any():
        return None
    labels = np.where(footprint, 0, -1).astype(np.int32)
    return mask_crops(image, labels, background="black")[0]


def object_footprint(
    object_alpha: np.ndarray,
    object_depth: np.ndarray,
    scene_depth: np.ndarray,
    *,
    depth_tolerance: float,
    relative_tolerance: float,
    min_alpha: float = 0.5,
) -> np.ndarray:
    """(H, W) bool: the pixels an object covers in the full render, occluders cut away.

    object_alpha / object_depth: (H, W) the object's Gaussians rendered alone (opacity, median
    depth); scene_depth: (H, W) the whole splat's median depth from the same camera. A pixel is
    the object's where the object alone is opaque (`min_alpha`) and nothing renders in front of
    it: its depth agrees with the scene's within the visibility test's tolerances.
    """
    tolerance = depth_tolerance + relative_tolerance * scene_depth
    return (object_alpha >= min_alpha) & (scene_depth > 0) & (object_depth <= scene_depth + tolerance)


def object_crops(
    gaussians: Gaussians,
    object_ids: np.ndarray,
    frames: Sequence[Any],
    best: np.ndarray,
    render: Any,
    *,
    depth_tolerance: float,
    relative_tolerance: float,
) -> dict[int, np.ndarray]:
    """Object id -> its crop from its best frame (`object_crop`), for every object with one.

    render(gaussians | None, frame) -> `RenderOutput`: the splat's renderer (None: the whole splat,
    else those Gaussians alone). Each best frame is rendered once in colour (the image and the
    scene depth), and each object alone in that frame for its footprint (`object_footprint`); an
    object whose footprint is empty (too small, or covered by others) has no crop.
    """
    crops: dict[int, np.ndarray] = {}
    for f in np.unique(best[best >= 0]):
        frame = frames[int(f)]
        scene = render(None, frame)
        image = to_uint8(scene.rgb)
        for obj in np.flatnonzero(best == f):
            alone = render(gaussians.subset(object_ids == obj), frame)
            footprint = object_footprint(
                alone.alpha,
                alone.median_depth,
                scene.median_depth,
                depth_tolerance=depth_tolerance,
                relative_tolerance=relative_tolerance,
            )
            crop = object_crop(image, footprint)
            if crop is not None:
                crops[int(obj)] = crop
    return crops


def rank_by_cosine(
    encoder: Encoder, crops: dict[int, np.ndarray], text: np.ndarray, answers: Sequence[int]
) -> tuple[list[list[int]], np.ndarray]:
    """Each task's answers, highest cosine first, and the (O', T) cosines of the embedded objects.

    text: (T, D) unit text embeddings; answers: how many objects each task takes (the full
    method's count for it). Returns (per task a list of object ids, at most `answers[t]` long;
    the cosines with rows in the order of `sorted(crops)`).
    """
    objects = sorted(crops)
    if not objects:
        return [[] for _ in answers], np.zeros((0, len(answers)), dtype=np.float32)
    embeddings = encoder.encode_images([crops[o] for o in objects]).astype(np.float32)
    cosines = embeddings @ np.asarray(text, dtype=np.float32).T  # (O', T)
    ranked: list[list[int]] = []
    for t, n in enumerate(answers):
        order = np.argsort(-cosines[:, t], kind="stable")[: max(int(n), 0)]
        ranked.append([objects[i] for i in order])
    return ranked, cosines


@dataclass
class PeSelection:
    """The row's selection: per task the chosen (object id, box in the cameras' frame), best first;
    `object_ids` (N,) the map's objects after the kNN filter on every candidate; `scores` (O, T)
    each object's score for LeRF (1 / rank for the objects a task chose, else 0)."""

    selection: dict[str, list[tuple[int, OrientedBox]]]
    object_ids: np.ndarray
    scores: np.ndarray
    num_objects: int
    selectable: int


def filtered_objects(
    means: np.ndarray, object_ids: np.ndarray, already: np.ndarray, num_objects: int, params: PipelineParams
) -> np.ndarray:
    """(N,) object ids with the kNN filter applied to every object, not only the full method's
    selected ones (`already`, filtered by its run): every candidate gets the same filter."""
    ids = np.asarray(object_ids, dtype=np.int64).copy()
    others = np.setdiff1d(np.unique(ids[ids >= 0]), already)
    remove_floaters(means, ids, others, num_objects, params)
    return ids


def rendered_crops(
    spec: Any, scene: Any, ids: np.ndarray, num_objects: int, device: str = "cpu"
) -> dict[int, np.ndarray]:
    """Object id -> the crop of its best view (steps 1-3), for the map `ids` (N,) of `num_objects`.

    spec / scene: a job that has run (`JobSpec`, `JobScene`): its parameters (depth source and
    tolerances), splat, training frames (`selected_frames`, as fused) and visibility cache.
    """
    from bayesian_fields_core.stages.fuse import LazyRenderer, frame_depth

    params: PipelineParams = spec.params
    means = np.asarray(scene.loaded.gaussians.means)
    indexed = list(scene.selected_frames)
    frames = [frame for _, frame in indexed]
    renderer = LazyRenderer(scene, device)
    centres = centre_columns(means, device)
    visible = []
    for index, frame in indexed:  # the fuse stage's cached pairs (its renders), else its test again
        key = scene.keys.visibility_key(index)
        if spec.cache_store.exists(key):
            visible.append(get_arrays(spec.cache_store, key)["gaussian_ids"].astype(np.int64))
            continue
        visible.append(
            visible_gaussians(
                centres,
                frame,
                frame_depth(params, renderer, frame),
                depth_tolerance=scene.lengths.depth_tolerance,
                relative_tolerance=params.depth_tolerance_relative,
                near=scene.lengths.visibility_near,
            )
        )
    best = best_views(visible_counts(ids, visible, num_objects))

    def render(part: Gaussians | None, frame: Any) -> Any:
        if part is None:
            return renderer().render(frame.K, frame.world_to_camera, frame.width, frame.height)
        alone = GaussianRenderer(part, device=device, near_plane=scene.lengths.render_near)
        return alone.render(frame.K, frame.world_to_camera, frame.width, frame.height)

    return object_crops(
        scene.loaded.gaussians,
        ids,
        frames,
        best,
        render,
        depth_tolerance=scene.lengths.depth_tolerance,
        relative_tolerance=params.depth_tolerance_relative,
    )


def pe_selection(
    spec: Any, scene: Any, result: Any, encoder: Encoder, text: np.ndarray, device: str = "cpu"
) -> PeSelection:
    """The w/o PE row's selection on the full method's map.

    spec / scene: the full row's job (`JobSpec`, `JobScene`): its parameters (depth source and
    tolerances, kNN filter), its splat and its training frames (`selected_frames`, as fused).
    result: the full row's `Result` (its object ids and each task's number of answers).
    text: (T, D) the tasks' text embeddings from `encoder`, in `spec.tasks` order.
    Boxes are in the cameras' frame (where the map is computed and the GT lives).
    """
    params: PipelineParams = spec.params
    tasks = list(spec.tasks)
    means = np.asarray(scene.loaded.gaussians.means)
    num_objects = int(result.num_objects)
    already = np.array(
        sorted({o.object_id for objs in result.selections.values() for o in objs}), dtype=np.int64
    )
    ids = filtered_objects(means, result.object_ids, already, num_objects, params)
    crops = rendered_crops(spec, scene, ids, num_objects, device)
    answers = [len(result.selections.get(task, [])) for task in tasks]
    ranked, _ = rank_by_cosine(encoder, crops, text, answers)
    chosen = np.array(sorted({o for objs in ranked for o in objs}), dtype=np.int64)
    _, _, boxes = object_geometry(means, ids, chosen, num_objects, scene.lengths.box_min_side)
    scores = np.zeros((num_objects, len(tasks)), dtype=np.float64)
    selection: dict[str, list[tuple[int, OrientedBox]]] = {}
    for t, (task, objs) in enumerate(zip(tasks, ranked, strict=True)):
        kept = [(o, boxes[o]) for o in objs if boxes[o] is not None]
        selection[task] = [(o, box) for o, box in kept if box is not None]
        for rank, (o, _) in enumerate(selection[task]):
            scores[o, t] = 1.0 / (rank + 1)
    return PeSelection(
        selection=selection, object_ids=ids, scores=scores, num_objects=num_objects, selectable=len(crops)
    )
