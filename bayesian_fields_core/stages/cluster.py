"""Stage 3, `cluster`: primitives -> p(y|x) -> edges -> AIB -> prune -> top-k -> kNN -> result.

METHOD steps 6-12. Runs on the CPU queue: it reads the fused probabilities, the per-mask
acceptance flags and the cached mask-to-Gaussian associations, and writes the result. The
algorithm itself is `objects.clustering`; this module only reads, orchestrates and stores.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from typing import Any

import numpy as np

from bayesian_fields_core.fusion.likelihood import resolve_likelihood
from bayesian_fields_core.fusion.peak import object_peak
from bayesian_fields_core.job.artifacts import ACCEPTED_KEY, FUSION_KEY, PRIMITIVES_KEY, RESULT_PREFIX
from bayesian_fields_core.job.job_scene import JobScene
from bayesian_fields_core.job.markers import is_done, read_marker, write_marker
from bayesian_fields_core.job.runner import Runner
from bayesian_fields_core.job.spec import JobSpec
from bayesian_fields_core.job.stage_table import STAGES
from bayesian_fields_core.job.store import get_arrays
from bayesian_fields_core.objects.clustering import ObjectMap, objects_from_primitives, primitive_scores
from bayesian_fields_core.objects.compile_kernels import prepare_kernels
from bayesian_fields_core.objects.not_found import not_found_reason, resolve_answer_min_peak
from bayesian_fields_core.objects.primitives import PrimitiveBuilder
from bayesian_fields_core.objects.timing import StepTimer
from bayesian_fields_core.perception.models import Models
from bayesian_fields_core.results.format import NotFound, Result, SelectedObject
from bayesian_fields_core.scene.scale import scene_units


def load_primitives(spec: JobSpec, scene: JobScene, runner: Runner) -> np.ndarray:
    """(N,) primitive ids (step 6): as `fuse` built them, or replayed from the cached
    associations for a job fused before `fuse` stored them."""
    key = spec.key(PRIMITIVES_KEY)
    if spec.store.exists(key):
        return get_arrays(spec.store, key)["primitive_ids"]
    return build_primitives(spec, scene, runner)


def build_primitives(spec: JobSpec, scene: JobScene, runner: Runner) -> np.ndarray:
    """Replay the primitive rule over the frames with the masks OR-phi accepted (step 6): every
    frame's associations are read again (at the scale bench, 300 files and 30 M pairs, ~2 s)."""
    builder = PrimitiveBuilder(len(scene.loaded.gaussians))
    for gaussian_ids, mask_ids, accepted in _accepted_frames(spec, scene, runner):
        builder.add_frame(gaussian_ids, mask_ids, accepted)
    return builder.primitive_ids


def view_counts(
    spec: JobSpec, scene: JobScene, runner: Runner, fused: dict[str, np.ndarray]
) -> np.ndarray | None:
    """(N,) accepted views per Gaussian when the per-view conditionals need them: as `fuse`
    stored them, or counted again from the accepted masks for a job fused before it stored
    them (the same count, so the map does not depend on when the job was fused)."""
    if spec.params.aib_conditionals != "per_view" or spec.params.fusion != "bayes":
        return None
    if "view_counts" in fused:
        return fused["view_counts"]
    counts = np.zeros(len(scene.loaded.gaussians), dtype=np.int32)
    for gaussian_ids, mask_ids, accepted in _accepted_frames(spec, scene, runner):
        counts[gaussian_ids[accepted[mask_ids]]] += 1  # masks are exclusive: once per frame
    return counts


def _accepted_frames(
    spec: JobSpec, scene: JobScene, runner: Runner
) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Each fused frame's cached associations (gaussian_ids (n,), mask_ids (n,)) with its masks'
    OR-phi flags (M,), in fusion order; the cancel check runs after each frame."""
    accepted = get_arrays(spec.store, spec.key(ACCEPTED_KEY))
    offsets = np.concatenate([[0], np.cumsum(accepted["mask_counts"])])
    for n, index in enumerate(accepted["frame_indices"]):
        vis = get_arrays(spec.cache_store, scene.keys.visibility_key(int(index)))
        yield vis["gaussian_ids"], vis["mask_ids"], accepted["accepted"][offsets[n] : offsets[n + 1]]
        runner.check_cancel()


def run(spec: JobSpec, scene: JobScene, runner: Runner) -> dict[str, Any]:
    """The cluster stage. The cancel check runs between every step (whichever way the primitives
    are found), and once more after the result is written: a cancel accepted while the result was
    being written removes it again, so a cancelled job never leaves result objects."""
    t0 = time.perf_counter()
    timer = StepTimer()
    params = spec.params
    runner.check_cancel()
    fused = get_arrays(spec.store, spec.key(FUSION_KEY))
    runner.progress("cluster", 0.05)
    with timer("primitives"):
        primitive_ids = load_primitives(spec, scene, runner)
    runner.check_cancel()
    runner.progress("cluster", 0.3)
    with timer("probabilities"):
        scores = primitive_scores(
            primitive_ids,
            fused["probabilities"],
            fused["logodds"],
            params,
            view_counts(spec, scene, runner, fused),
        )
    runner.check_cancel()
    with timer("kernels"):  # seconds once per machine (numba compiles), said when it happens
        prepare_kernels()
    object_map = objects_from_primitives(
        scene.loaded.gaussians.means,
        primitive_ids,
        scores.pyx,
        params,
        scores.relevance,
        scores.evidence,
        lengths=scene.lengths,
        checkpoint=runner.check_cancel,
        premerge=scores.premerge,
    )
    timer.seconds.update(object_map.timings)
    timer.cpu_seconds.update(object_map.cpu_timings)
    runner.progress("cluster", 0.8)
    with timer("write"):
        stage_timings = _stage_timings(spec)
        stage_timings["cluster"] = time.perf_counter() - t0
        result = build_result(spec, scene, runner.models, object_map, stage_timings, fused.get("peak_margin"))
    runner.check_cancel()
    sizes = _write_result_or_nothing(spec, scene, runner, result, timer)
    runner.progress("cluster", 1.0)
    report = {
        "seconds": time.perf_counter() - t0,
        "timings": timer.seconds,
        "cpu_timings": timer.cpu_seconds,
        "counts": object_map.counts,
    }
    return write_marker(spec, "cluster", {**report, "result_bytes": sizes})


def _write_result_or_nothing(
    spec: JobSpec, scene: JobScene, runner: Runner, result: Result, timer: StepTimer
) -> dict[str, Any]:
    """Write the result; on a cancel during the write, or accepted by the time it ends, or on any
    failure part-way, delete what was written (a store has no atomic rename of a folder, so
    "all or nothing" is: write, check, else remove)."""
    from bayesian_fields_core.results.writer import write_result

    prefix = spec.key(RESULT_PREFIX)
    params = spec.params
    try:
        sizes = write_result(  # times its steps "write" (arrays, summary), "exports", "previews"
            spec.store,
            prefix,
            result,
            gaussians=scene.loaded.splat_frame_gaussians() if params.export_ply else None,
            export_ply=params.export_ply,
            frames=scene.loaded.frames,
            preview_max_side=params.preview_max_side if params.previews else None,
            scene=_scene_record(scene),
            timer=timer,
        )
        runner.check_cancel()
    except BaseException:
        spec.store.delete_prefix(prefix)
        raise
    return sizes


def _scene_record(scene: JobScene) -> dict[str, Any]:
    """Where the result's scene lives, for `bfields view`: as its source says (a local folder or
    a store prefix, `SceneOrigin.record`), with its size."""
    return {
        **scene.origin.record(),
        "num_gaussians": len(scene.loaded.gaussians),
        "num_frames": len(scene.loaded.frames),
    }


def build_result(
    spec: JobSpec,
    scene: JobScene,
    models: Models,
    object_map: ObjectMap,
    timings: dict[str, float],
    peak: np.ndarray | None = None,
) -> Result:
    """The serialisable result: id maps, probability table, per-task selections, provenance.

    `peak` (N, T) is each Gaussian's best-view margin (`fusion.peak`); a task whose best object's
    peak is below `answer_min_peak` gets an empty selection and a `NotFound` reason
    (`objects.not_found`). The map is computed in the cameras' frame (where the loader put the
    Gaussians); boxes and centroids are reported in the splat file's frame and, when the loader
    applied a transform, also in the capture frame (`SelectedObject.capture_*`), and when the
    camera file has an `applied_transform`, in the data's world frame (`SelectedObject.world_*`).
    Each selected object carries the score it was ranked by (`SelectedObject.score`).
    """
    loaded = scene.loaded
    params = spec.params
    to_capture = loaded.splat_to_capture
    to_splat = None if to_capture is None else to_capture.inverse()
    to_world = loaded.capture_to_world
    ranking = object_map.ranking
    selections: dict[str, list[SelectedObject]] = {}
    not_found: dict[str, NotFound] = {}
    scores = object_map.task_scores
    members: dict[int, np.ndarray] = {}
    threshold = resolve_answer_min_peak(
        params.answer_min_peak,
        models.calibration,
        resolve_likelihood(params, models.calibration),
    )
    for t, task in enumerate(spec.tasks):
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
                    world_centroid=None if to_world is None else to_world.points(centroid),
                    world_box=None if to_world is None else to_world.box(box),
                    score=None if ranking is None else float(ranking[obj, t]),
                    peak=None
                    if peak is None
                    else object_peak(
                        peak, members.setdefault(obj, np.flatnonzero(object_map.object_ids == obj)), t
                    ),
                )
            )
        best = chosen[0] if chosen else None
        missing = not_found_reason(
            None if best is None else best.object_id,
            None if best is None else best.peak,
            threshold if peak is not None else None,
        )
        if missing is not None:
            not_found[task], chosen = missing, []
        selections[task] = chosen
    return Result(
        tasks=list(spec.tasks),
        object_ids=object_map.object_ids,
        probabilities=object_map.probabilities.astype(np.float32),
        relevance=None if object_map.relevance is None else object_map.relevance.astype(np.float32),
        selections=selections,
        primitive_ids=object_map.primitive_ids if params.store_primitive_ids else None,
        # the threshold as applied ('calibrated' resolved to the encoder calibration's number)
        parameters=params.model_dump(mode="json") | {"answer_min_peak": threshold},
        models=models.model_ids,
        timings_s=timings,
        num_primitives=int(object_map.counts.get("primitives", 0)),
        splat_to_capture=None if to_capture is None else to_capture.matrix,
        layout=loaded.layout,
        not_found=not_found,
        capture_to_world=None if to_world is None else to_world.matrix,
        scene_scale={**scene.lengths.record(), "units": scene_units(loaded)},
        ranked_by=params.selection_score,
        splat_digest=scene.keys.splat_digest(),
    )


def _stage_timings(spec: JobSpec) -> dict[str, float]:
    return {
        stage: float(read_marker(spec, stage).get("seconds", 0.0))
        for stage in STAGES[: STAGES.index("cluster")]
        if is_done(spec, stage)
    }
